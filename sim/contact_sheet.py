"""Contact sheet of the simulated tasks: a start state and a goal example for each, as a person and the model see it.

python -m sim.contact_sheet docs/contact_sheet.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium
import numpy as np
from PIL import Image, ImageDraw

from sim import TASKS
from sim.goals import make_goal_examples

TILE = 256
LABEL_HEIGHT = 22
COLUMNS = ("start (display)", "goal (display)", "start (model 48px)", "goal (model 48px)")


def _upscale(image: np.ndarray) -> Image.Image:
    return Image.fromarray(image).resize((TILE, TILE), Image.Resampling.NEAREST)


def make_contact_sheet(seed: int = 0, image_size: int = 48) -> Image.Image:
    """One row per task: start and goal views at display size, then the same two at the model's resolution."""
    rows: list[tuple[str, list[Image.Image]]] = []
    for task, env_id in TASKS.items():
        env = gymnasium.make(env_id, image_size=image_size, render_mode="rgb_array", render_size=TILE)
        start_obs, _ = env.reset(seed=seed)
        start_display = env.render()
        env.close()
        goal = make_goal_examples(task, 1, seed=seed, image_size=image_size, display_size=TILE)[0]
        tiles = [
            Image.fromarray(start_display),
            Image.fromarray(goal.display),
            _upscale(start_obs),
            _upscale(goal.image),
        ]
        rows.append((f"{task} ({env_id})", tiles))

    width = TILE * len(COLUMNS)
    height = len(rows) * (TILE + LABEL_HEIGHT) + LABEL_HEIGHT
    sheet = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(sheet)
    for column, title in enumerate(COLUMNS):
        draw.text((column * TILE + 6, 5), title, fill="black")
    for row, (label, tiles) in enumerate(rows):
        top = LABEL_HEIGHT + row * (TILE + LABEL_HEIGHT)
        draw.text((6, top + 5), label, fill="black")
        for column, tile in enumerate(tiles):
            sheet.paste(tile, (column * TILE, top + LABEL_HEIGHT))
    return sheet


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Write a contact sheet of the simulated tasks' start and goal images.")
    parser.add_argument("out", type=Path, nargs="?", default=Path("docs/contact_sheet.png"), help="PNG to write")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    make_contact_sheet(seed=args.seed).save(args.out)
    print(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
