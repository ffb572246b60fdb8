"""A small line plot drawn with Pillow (no plotting library needed): curves against env steps."""

from collections.abc import Sequence
from pathlib import Path
from typing import IO

from PIL import Image, ImageDraw, ImageFont

COLOURS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b"]


def line_plot(
    path: Path | IO[bytes],
    series: dict[str, Sequence[tuple[float, float]]],
    *,
    title: str,
    x_label: str = "env steps",
    y_range: tuple[float, float] | None = None,
    x_max: float | None = None,
    size: tuple[int, int] = (900, 500),
    bands: dict[str, Sequence[tuple[float, float, float]]] | None = None,
) -> None:
    """Each series is a list of (x, y); `bands` gives a series a shaded (x, low, high) spread, drawn under the
    lines in the series' colour. y_range None: fitted to the data (each series is drawn on it); x_max None: the
    data's largest x."""
    width, height = size
    left, right, top, bottom = 70, 30, 40, 60
    bands = bands or {}
    image = Image.new("RGB", size, "white")
    draw = ImageDraw.Draw(image)
    font = ImageFont.load_default(size=12)
    points = [point for values in series.values() for point in values]
    x_max = x_max or max((x for x, _ in points), default=1.0) or 1.0
    if y_range is None:
        ys = [y for _, y in points] or [0.0, 1.0]
        y_range = (min(0.0, min(ys)), max(ys) if max(ys) > min(0.0, min(ys)) else 1.0)
    y_low, y_high = y_range

    def to_pixel(x: float, y: float) -> tuple[float, float]:
        px = left + (width - left - right) * x / x_max
        py = height - bottom - (height - top - bottom) * (y - y_low) / ((y_high - y_low) or 1.0)
        return px, py

    shade = Image.new("RGB", size, "white")
    shade_draw = ImageDraw.Draw(shade)
    for index, name in enumerate(series):
        band = bands.get(name, [])
        if len(band) > 1:
            outline = [to_pixel(x, high) for x, _, high in band] + [to_pixel(x, low) for x, low, _ in reversed(band)]
            shade_draw.polygon(outline, fill=COLOURS[index % len(COLOURS)])
    if bands:  # each band a quarter of its colour's strength on the white plot, under everything drawn next
        image = Image.blend(image, shade, 0.25)
        draw = ImageDraw.Draw(image)
    draw.rectangle([left, top, width - right, height - bottom], outline="black")
    for tick in range(6):
        y = y_low + (y_high - y_low) * tick / 5
        _, py = to_pixel(0, y)
        draw.line([left - 5, py, left, py], fill="black")
        draw.text((5, py - 6), f"{y:.3g}", fill="black", font=font)
        x = x_max * tick / 5
        px, _ = to_pixel(x, y_low)
        draw.line([px, height - bottom, px, height - bottom + 5], fill="black")
        draw.text((px - 15, height - bottom + 8), f"{x:,.0f}", fill="black", font=font)
    draw.text((width // 2 - 40, height - 25), x_label, fill="black", font=font)
    draw.text((left, 12), title, fill="black", font=font)
    for index, (name, values) in enumerate(series.items()):
        colour = COLOURS[index % len(COLOURS)]
        pixels = [to_pixel(x, y) for x, y in values]
        if len(pixels) > 1:
            draw.line(pixels, fill=colour, width=2)
        for px, py in pixels:
            draw.ellipse([px - 2, py - 2, px + 2, py + 2], fill=colour)
        draw.text((width - right - 220, top + 8 + 16 * index), f"- {name}", fill=colour, font=font)
    image.save(path, format="PNG")
