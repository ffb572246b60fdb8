"""Uploaded goal photos: decode and check them, then make the model's and the display's PNG copies.

Only PNG, JPEG and WebP are accepted. A JPEG with an MPF segment (phone portrait or HDR photos; Pillow
calls it "MPO") is a JPEG: its first frame, the picture itself, is used and it is stored as image/jpeg.
Every check happens before anything is stored, and every failure is an `ImageRejected` whose message
says what was wrong with which file.
"""

import io
import warnings
from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

ACCEPTED_FORMATS: dict[str, str] = {
    "PNG": "image/png",
    "JPEG": "image/jpeg",
    "MPO": "image/jpeg",  # JPEG + MPF (Samsung/Android portrait, iOS HDR); every viewer shows the first frame
    "WEBP": "image/webp",
}
DISPLAY_MAX_SIDE = 256


class ImageRejected(ValueError):
    """An upload that cannot be used; `status_code` is 400 (bad image) or 413 (too large)."""

    def __init__(self, message: str, *, status_code: int = 400) -> None:
        super().__init__(message)
        self.message = message
        self.status_code = status_code


@dataclass(frozen=True)
class PreparedImage:
    """One checked upload, ready to store."""

    filename: str
    original: bytes
    media_type: str
    width: int
    height: int
    model_png: bytes
    display_png: bytes


def decode_upload(data: bytes, *, max_bytes: int, max_pixels: int) -> Image.Image:
    """Decode PNG, JPEG or WebP bytes into an RGB image, fully loaded and upright (EXIF orientation).

    Raises ImageRejected: empty, above `max_bytes` (413), not an image or another format, truncated,
    or more than `max_pixels` pixels (a decompression bomb, 413).
    """
    if not data:
        raise ImageRejected("the file is empty")
    if len(data) > max_bytes:
        raise ImageRejected(f"the file is {len(data):,} bytes; the limit is {max_bytes:,} bytes", status_code=413)
    # Pillow warns above MAX_IMAGE_PIXELS and refuses above twice that; we refuse above it (the check
    # on the header's size below comes first, this is the second line of defence).
    Image.MAX_IMAGE_PIXELS = max_pixels
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            image = Image.open(io.BytesIO(data))
            if image.format not in ACCEPTED_FORMATS:
                raise ImageRejected(f"{image.format or 'this'} images are not accepted; use PNG, JPEG or WebP")
            width, height = image.size
            if width * height > max_pixels:
                raise ImageRejected(
                    f"the image is {width}x{height} = {width * height:,} pixels; the limit is {max_pixels:,}",
                    status_code=413,
                )
            if width < 1 or height < 1:
                raise ImageRejected("the image has no pixels")
            image.load()  # an MPO opens on its first frame, the photo; the others are never decoded
            image = ImageOps.exif_transpose(image)
    except ImageRejected:
        raise
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as error:
        raise ImageRejected(f"the image has too many pixels: {error}", status_code=413) from error
    except UnidentifiedImageError as error:
        raise ImageRejected("not an image Pillow can read; use PNG, JPEG or WebP") from error
    except (OSError, SyntaxError, ValueError, EOFError) as error:  # truncated or corrupt data
        raise ImageRejected(f"the image is damaged or truncated ({error})") from error
    return _to_rgb(image)


def _to_rgb(image: Image.Image) -> Image.Image:
    """Flatten transparency onto white (as the image looks in a viewer) and drop other modes."""
    if image.mode in ("RGBA", "LA") or (image.mode == "P" and "transparency" in image.info):
        rgba = image.convert("RGBA")
        background = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
        return Image.alpha_composite(background, rgba).convert("RGB")
    return image.convert("RGB")


def center_square(image: Image.Image) -> Image.Image:
    width, height = image.size
    side = min(width, height)
    left, top = (width - side) // 2, (height - side) // 2
    return image.crop((left, top, left + side, top + side))


def _png_bytes(image: Image.Image) -> bytes:
    buffer = io.BytesIO()
    image.save(buffer, format="PNG", optimize=True)
    return buffer.getvalue()


def model_view(image: Image.Image, size: int) -> Image.Image:
    """What the networks see of a picture: centre-cropped to a square, resized to size x size (area filter)."""
    square = center_square(image.convert("RGB"))
    return square.resize((size, size), Image.Resampling.LANCZOS, reducing_gap=3.0)


def to_png(image: Image.Image, size: int) -> bytes:
    """The model's view (model_view) as PNG."""
    return _png_bytes(model_view(image, size))


def model_array(original: bytes, size: int) -> np.ndarray:
    """The model's view, (size, size, 3) uint8, of an upload that was accepted before (upright, transparency
    flattened onto white, as prepare_upload makes its model copy)."""
    with Image.open(io.BytesIO(original)) as opened:
        opened.load()
        image = ImageOps.exif_transpose(opened)
    return np.asarray(model_view(_to_rgb(image), size))


def to_display_png(image: Image.Image, max_side: int = DISPLAY_MAX_SIDE) -> bytes:
    """A copy for people: the whole picture, aspect kept, no side above `max_side`."""
    display = image.convert("RGB").copy()
    display.thumbnail((max_side, max_side), Image.Resampling.LANCZOS)
    return _png_bytes(display)


def prepare_upload(data: bytes, *, filename: str, model_size: int, max_bytes: int, max_pixels: int) -> PreparedImage:
    """Check one upload and make its copies; ImageRejected's message names the file."""
    try:
        image = decode_upload(data, max_bytes=max_bytes, max_pixels=max_pixels)
    except ImageRejected as error:
        raise ImageRejected(f"{filename}: {error.message}", status_code=error.status_code) from error
    with Image.open(io.BytesIO(data)) as header:
        media_type = ACCEPTED_FORMATS[header.format or ""]
    return PreparedImage(
        filename=filename,
        original=data,
        media_type=media_type,
        width=image.width,
        height=image.height,
        model_png=to_png(image, model_size),
        display_png=to_display_png(image),
    )


def decoded_array(data: bytes) -> np.ndarray:
    """Stored PNG (or other image) bytes as (height, width, 3) uint8 RGB, at the size they were stored."""
    with Image.open(io.BytesIO(data)) as image:
        return np.array(image.convert("RGB"))


STRUCTURE_SIDE = 32
"""Side of the model's view the structure descriptor is taken from."""
STRUCTURE_CELLS = 2
"""The view is split into STRUCTURE_CELLS x STRUCTURE_CELLS cells, each with its own orientation histogram."""
STRUCTURE_BINS = 8
"""Edge orientations (0-180 degrees) per histogram."""
VIEWPOINT_SIMILARITY = 0.3
"""A photo whose median structure similarity to the set's other photos is below this is from another viewpoint
(photos of the pusher from its task camera: 0.5 or more to one another, brighter or not; from above: under 0.05)."""
VIEWPOINT_MIN_PHOTOS = 3
"""Other photos a set needs before a photo is compared with them."""


def structure_descriptor(image: Image.Image) -> np.ndarray:
    """Where the edges of the model's view run: a histogram of gradient orientations weighted by their strength in
    each of STRUCTURE_CELLS^2 cells of the centre square, scaled to unit length. It does not change when the light
    is brighter or darker (only its balance, not its scale, enters), but does when the camera looks from elsewhere."""
    gray = np.asarray(model_view(image, STRUCTURE_SIDE).convert("L"), dtype=np.float64)
    dy, dx = np.gradient(gray)
    strength = np.hypot(dx, dy)
    orientation = np.minimum((np.mod(np.arctan2(dy, dx), np.pi) / np.pi * STRUCTURE_BINS).astype(int),
                             STRUCTURE_BINS - 1)  # fmt: skip
    cell = STRUCTURE_SIDE // STRUCTURE_CELLS
    histograms = [
        np.bincount(
            orientation[row : row + cell, col : col + cell].ravel(),
            weights=strength[row : row + cell, col : col + cell].ravel(), minlength=STRUCTURE_BINS,
        )
        for row in range(0, STRUCTURE_SIDE, cell) for col in range(0, STRUCTURE_SIDE, cell)
    ]  # fmt: skip
    descriptor = np.concatenate(histograms)
    norm = float(np.linalg.norm(descriptor))
    return descriptor / norm if norm > 0 else descriptor


def viewpoint_similarity(photo: Image.Image, others: list[Image.Image]) -> float | None:
    """The median cosine similarity of the photo's structure descriptor to the other photos' (1: the same edges in
    the same places); None with fewer than VIEWPOINT_MIN_PHOTOS others."""
    if len(others) < VIEWPOINT_MIN_PHOTOS:
        return None
    mine = structure_descriptor(photo)
    return float(np.median([float(mine @ structure_descriptor(other)) for other in others]))
