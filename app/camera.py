"""The server's view through a robot's camera: the goal-set page's live view, its Capture, and the check of an
uploaded photo against what the camera sees.

Which envs have a camera: the allowed envs (the project's stand-in robot and RAQ_ENV_MODULES's envs, the ids a
learner can make) whose class, read from gymnasium's registry entry point without making the env, is a
`robot.base.RobotEnv` that implements `read_camera`.

The server never opens a camera or makes a robot's env: the robot's own process (`raq robot ENV`,
robot/drive/process.py) owns camera and arm and publishes frames to the store, often while a page watches (this
server says so, Store.watch_robot); while a run's actor drives the robot, its frames are the run's
(Store.robot_runs). So a camera that opens in one process at a time (most USB cameras) serves the live view and a
run at once, and no page can move or hold an arm.
"""

import io
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from PIL import Image

from contract.envs import SIM_ENV_IDS, env_class, module_env_ids
from contract.images import VIEWPOINT_SIMILARITY, model_view, viewpoint_similarity
from contract.store import NotFound, Store
from robot.base import is_robot

PROJECT_ROBOT_MODULES = ("robot.standin",)
"""The project's own robots offered everywhere (robot.template is a file to copy, not a robot)."""
FRAME_INTERVAL_S = 0.2
"""The store is asked for a camera's frame at most this often; requests in between get the last answer."""
WATCH_EVERY_S = 1.0
"""How often this server tells a robot's process that a page watches its camera."""

ASPECT_TOLERANCE = 0.10
"""The photo's width/height may differ from the camera frame's by this fraction before it is a warning."""
SMALL_PHOTO_FRACTION = 0.5
"""A photo whose shorter side is under this fraction of the camera frame's shorter side is much smaller."""
COLOUR_MEAN_TOLERANCE = 40.0
"""A colour channel's mean (0-255, over what the model sees) may differ by this much before it is a warning."""
CONTRAST_RATIO_LIMIT = 2.0
"""The photo's brightness spread (standard deviation) may be this many times the camera's, or its inverse."""
STATS_SIDE = 64
"""Colours are compared on both images' centre squares at this side (what the model sees of each)."""
CHANNELS = ("red", "green", "blue")


class CameraUnavailable(RuntimeError):
    """No process publishes the robot's frames, or the one that has the camera has published none yet."""


class CameraFrame:
    """One frame of a robot's camera: the PNG (as served and stored) and its pixels, (height, width, 3) uint8."""

    def __init__(self, *, env_id: str, png: bytes, source: str, pixels: np.ndarray | None = None) -> None:
        self.env_id, self.png, self.source = env_id, png, source
        self.taken_at = time.monotonic()
        self._pixels = pixels
        if pixels is None:
            with Image.open(io.BytesIO(png)) as header:
                self.width, self.height = header.size
        else:
            self.height, self.width = pixels.shape[:2]

    @property
    def pixels(self) -> np.ndarray:
        if self._pixels is None:
            with Image.open(io.BytesIO(self.png)) as image:
                self._pixels = np.asarray(image.convert("RGB"))
        return self._pixels


# ---------------------------------------------------------------- which envs have a camera
@lru_cache(maxsize=8)
def _camera_env_ids(modules: tuple[str, ...]) -> tuple[str, ...]:
    candidates = list(SIM_ENV_IDS)
    for module in dict.fromkeys((*PROJECT_ROBOT_MODULES, *modules)):
        try:
            candidates += module_env_ids(module)
        except Exception:  # noqa: BLE001, S112 - a module that cannot be imported has no camera to offer
            continue
    found = []
    for env_id in candidates:
        try:
            if is_robot(env_class(env_id)):
                found.append(env_id)
        except Exception:  # noqa: BLE001, S112 - an entry point that does not import is no camera either
            continue
    return tuple(found)


def camera_env_ids(env_modules: Iterable[str]) -> list[str]:
    """The robot env ids with a camera, of the stand-in and the allowed modules (found once a process)."""
    return list(_camera_env_ids(tuple(env_modules)))


# ---------------------------------------------------------------- the frames the robots publish
class CameraSource:
    """The robots' cameras as this server sees them (see the module's docstring); safe to share between threads."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._checked: dict[tuple[int, str], tuple[float, CameraFrame | str]] = {}
        self._watched: dict[tuple[int, str], float] = {}

    def frame(self, env_id: str, store: Store) -> CameraFrame:
        """The camera's newest frame as its robot's process (or a run's actor) published it, looked up at most
        every FRAME_INTERVAL_S per store and env id. Raises CameraUnavailable with the reason when there is none."""
        now, key = time.monotonic(), (id(store), env_id)
        with self._lock:
            checked = self._checked.get(key)
        if checked is None or now - checked[0] >= FRAME_INTERVAL_S:
            checked = (now, self._published_frame(env_id, store, key))
            with self._lock:
                self._checked[key] = checked
        if isinstance(checked[1], str):
            raise CameraUnavailable(checked[1])
        return checked[1]

    def _published_frame(self, env_id: str, store: Store, key: tuple[int, str]) -> CameraFrame | str:
        """The newest frame of env_id: its driving actor's while a run's actor drives the robot, else its robot
        process's (marked watched, so that it publishes often); the reason when there is none."""
        for robot in store.robot_runs():
            try:
                if store.get_run(run_id=robot.run_id).env_id != env_id:
                    continue
                published = store.camera_frame(run_id=robot.run_id)
            except NotFound:  # the run was deleted since it was listed
                continue
            if published is None:
                return f"{env_id}: run {robot.run_id}'s actor drives this robot and has published no camera frame yet"
            return CameraFrame(env_id=env_id, png=published[0], source=f"run {robot.run_id}")
        process = store.robot_process_of(env_id=env_id)
        if process is not None:
            now = time.monotonic()
            with self._lock:
                due = now - self._watched.get(key, -WATCH_EVERY_S) >= WATCH_EVERY_S
                if due:
                    self._watched[key] = now
            if due:
                store.watch_robot(robot=process.robot)
            published = store.robot_process_frame(robot=process.robot)
            if published is None:
                return f"{env_id}: the robot's process ({process.robot}) has published no camera frame yet"
            return CameraFrame(env_id=env_id, png=published[0], source=f"robot {process.robot}")
        claimed = store.claimed_run_of(env_id=env_id)
        if claimed is not None:
            return f"{env_id}: run {claimed}'s actor is taking the camera; its frames follow once it has started"
        return (
            f"{env_id}: no robot process serves this camera: start `raq robot {env_id}` on the robot's host "
            "(or list it in RAQ_ROBOTS for `raq up`)"
        )


cameras = CameraSource()
"""This server's view of the robots' cameras."""


# ---------------------------------------------------------------- a photo beside the camera's frame
@dataclass(frozen=True)
class PhotoDifference:
    """One way an uploaded photo differs from the camera's frame, in plain words."""

    kind: str
    """aspect, size, colour, contrast, or viewpoint."""
    message: str


def _ratio_words(width: int, height: int) -> str:
    ratio = width / height
    for name, value in (("square", 1.0), ("4:3", 4 / 3), ("3:4", 3 / 4), ("3:2", 1.5), ("2:3", 2 / 3),
                        ("16:9", 16 / 9), ("9:16", 9 / 16)):  # fmt: skip
        if abs(ratio / value - 1) < 0.02:
            return f"{width}×{height} ({name})"
    return f"{width}×{height} ({ratio:.2f}:1)"


def _stats(image: Image.Image) -> tuple[np.ndarray, float]:
    """Per-channel means and the brightness's standard deviation of what the model sees (the centre square)."""
    pixels = np.asarray(model_view(image, STATS_SIDE), dtype=np.float64)
    brightness = pixels @ np.array([0.299, 0.587, 0.114])
    return pixels.reshape(-1, 3).mean(axis=0), float(brightness.std())


def photo_differences(photo: Image.Image, frame: np.ndarray, model_size: int) -> list[PhotoDifference]:
    """How `photo` differs from the camera's `frame` in ways that make goal photos and observations look unlike:
    shape (ASPECT_TOLERANCE), size (below the model's side, or SMALL_PHOTO_FRACTION of the frame's),
    colours (COLOUR_MEAN_TOLERANCE) and contrast (CONTRAST_RATIO_LIMIT). Empty when they look alike."""
    found: list[PhotoDifference] = []
    width, height = photo.size
    frame_height, frame_width = frame.shape[:2]
    if abs((width / height) / (frame_width / frame_height) - 1) > ASPECT_TOLERANCE:
        found.append(PhotoDifference(
            "aspect",
            f"Different shape: the photo is {_ratio_words(width, height)}, the camera's frame "
            f"{_ratio_words(frame_width, frame_height)}. The model sees the centre square of each, so they show "
            "different parts of the scene.",
        ))  # fmt: skip
    side, frame_side = min(width, height), min(frame_width, frame_height)
    if side < model_size:
        found.append(PhotoDifference(
            "size",
            f"Too small: the photo's shorter side is {side} px, less than the model's {model_size} px image, so it "
            "is enlarged and blurred.",
        ))  # fmt: skip
    elif side < SMALL_PHOTO_FRACTION * frame_side:
        found.append(PhotoDifference(
            "size",
            f"Much smaller than the camera's frame: {width}×{height} against {frame_width}×{frame_height} "
            f"(its shorter side is {round(100 * side / frame_side)}% of the camera's).",
        ))  # fmt: skip
    photo_mean, photo_spread = _stats(photo)
    frame_mean, frame_spread = _stats(Image.fromarray(frame))
    apart = [
        (name, p, f) for name, p, f in zip(CHANNELS, photo_mean, frame_mean, strict=True)
        if abs(p - f) > COLOUR_MEAN_TOLERANCE
    ]  # fmt: skip
    if apart:
        signs = {p > f for _, p, f in apart}
        overall = (
            "the photo is much brighter" if signs == {True} and len(apart) == 3
            else "the photo is much darker" if signs == {False} and len(apart) == 3
            else "the photo has another colour cast"
        )  # fmt: skip
        channels = ", ".join(f"{name} {p:.0f} against {f:.0f}" for name, p, f in apart)
        found.append(PhotoDifference(
            "colour",
            f"Different colours: {overall} (average {channels}, of 255; more than {COLOUR_MEAN_TOLERANCE:.0f} apart).",
        ))  # fmt: skip
    ratio = (photo_spread + 1.0) / (frame_spread + 1.0)
    if ratio > CONTRAST_RATIO_LIMIT or ratio < 1 / CONTRAST_RATIO_LIMIT:
        how = "harsher" if ratio > 1 else "flatter"
        found.append(PhotoDifference(
            "contrast",
            f"Different contrast: the photo's light is {how} (brightness spread {photo_spread:.0f} against the "
            f"camera's {frame_spread:.0f}).",
        ))  # fmt: skip
    return found


def viewpoint_difference(photo: Image.Image, set_photos: list[Image.Image]) -> PhotoDifference | None:
    """The photo is from another viewpoint than the set's other photos: its edges run elsewhere than theirs
    (contract.images.viewpoint_similarity below VIEWPOINT_SIMILARITY), whatever its brightness. None when it looks
    like them, or the set has too few photos to tell."""
    similarity = viewpoint_similarity(photo, set_photos)
    if similarity is None or similarity >= VIEWPOINT_SIMILARITY:
        return None
    return PhotoDifference(
        "viewpoint",
        f"Another viewpoint: the photo's edges and shapes are unlike those of the set's {len(set_photos)} other "
        f"photos (structure similarity {similarity:.2f}, below {VIEWPOINT_SIMILARITY:.2f}). Take goal photos from "
        "the robot camera's point of view.",
    )
