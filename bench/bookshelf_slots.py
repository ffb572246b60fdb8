"""Which slot does a learned bookshelf policy use, from where it starts? Several right answers, from one classifier.

    MUJOCO_GL=egl python bench/bookshelf_slots.py docs/results/seeds/bookshelf-vice_raq-seed0 \
        --out docs/results/bookshelf-slots.png
    MUJOCO_GL=egl python bench/bookshelf_slots.py --scripted    # the scripted controller (nearer slot), as a yardstick

Runs the run's best evaluated policy (data/checkpoints/run-*/policy-best.pt, else policy.pt) deterministically
for one episode from each of the env's resets with seeds 0 to EPISODES - 1 (the book's start drawn across the
shelf), and prints, by where the book started, the slot it was put into (left, right or none) and the step. With
--out it draws the episodes from the leftmost and the rightmost start as two rows of frames (the env's 256 px
render, every FRAME_EVERY steps up to the success).
"""

import argparse
import os
import sys
from collections.abc import Callable
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import gymnasium  # noqa: E402
import numpy as np  # noqa: E402
from PIL import Image, ImageDraw, ImageFont  # noqa: E402

import sim  # noqa: E402, F401 - registers the tasks
from sim.bookshelf import VisualBookshelfEnv  # noqa: E402
from sim.scripted import bookshelf_action  # noqa: E402

EPISODES = 20
"""Episodes, one per reset seed."""
FRAME_EVERY = 2
"""Steps between two frames of the figure."""
FRAMES = 6
"""The most frames in a row of the figure (the last is the success, or the episode's end)."""
SLOT_NAMES = ("left", "right")


def policy_file(run_dir: Path, names: tuple[str, ...] = ("policy-best.pt", "policy.pt")) -> Path:
    """The run's first policy of `names` that it has: by default its best evaluated one, else its latest."""
    for name in names:
        found = sorted(run_dir.glob(f"**/checkpoints/run-*/{name}"))
        if found:
            return found[-1]
    raise SystemExit(f"no {' or '.join(names)} under {run_dir}")


def episode(env: gymnasium.Env, act: Callable[[np.ndarray, gymnasium.Env], np.ndarray], seed: int) -> dict:
    """One episode from the reset of `seed`: where the book started (x), the slot used (or None), the step it was
    reached, the frames."""
    observation, info = env.reset(seed=seed)
    start_x = float(info["hand_pos"][0])
    frames, slot, reached = [env.render()], None, None
    for step in range(1, 101):
        observation, _, _, truncated, info = env.step(act(observation, env))
        if step % FRAME_EVERY == 0 or info["success"]:
            frames.append(env.render())
        if info["success"]:
            slot, reached = int(info["slot"]), step
            break
        if truncated:
            break
    return {"start_x": start_x, "slot": slot, "step": reached, "frames": frames}


def strip(frames: list[np.ndarray], label: str) -> Image.Image:
    """A row of at most FRAMES frames (evenly chosen, the last kept), captioned."""
    chosen = [frames[round(i)] for i in np.linspace(0, len(frames) - 1, min(FRAMES, len(frames)))]
    size = chosen[0].shape[0]
    row = Image.new("RGB", (size * len(chosen), size + 22), "white")
    for index, frame in enumerate(chosen):
        row.paste(Image.fromarray(frame), (index * size, 22))
    ImageDraw.Draw(row).text((6, 3), label, fill="black", font=ImageFont.load_default(size=15))
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, nargs="?", help="a bench/learn.py run directory of the bookshelf")
    parser.add_argument("--scripted", action="store_true", help="the scripted controller instead of a policy")
    parser.add_argument("--out", type=Path, default=None, help="the figure (PNG)")
    args = parser.parse_args()
    if args.scripted:

        def act(_observation: np.ndarray, env: gymnasium.Env) -> np.ndarray:
            return bookshelf_action(env.unwrapped)  # type: ignore[arg-type]

        source = "the scripted controller"
    elif args.run is not None:
        from learner.policy import load_policy  # noqa: PLC0415 - torch only for a learned policy

        path = policy_file(args.run)
        policy = load_policy(path)
        act, source = policy.env_action, f"{path} (step {policy.step})"
    else:
        parser.error("give a run directory or --scripted")
    env = gymnasium.make("VisualBookshelf-v0", render_mode="rgb_array")
    task: VisualBookshelfEnv = env.unwrapped  # type: ignore[assignment]
    episodes = sorted((episode(env, act, seed) for seed in range(EPISODES)), key=lambda result: result["start_x"])
    slots_at = ", ".join(f"{x * 100:+.0f} cm" for x in task.slot_x)
    print(f"{source}: the slot used from each start (the empty slots at x = {slots_at})")
    print("| start x | slot | step |\n| --- | --- | --- |")
    for result in episodes:
        slot = "none" if result["slot"] is None else SLOT_NAMES[result["slot"]]
        print(f"| {result['start_x'] * 100:+.1f} cm | {slot} | {result['step'] or '-'} |")
    used = {result["slot"] for result in episodes} - {None}
    print(f"slots used: {', '.join(SLOT_NAMES[s] for s in sorted(used)) or 'none'}")
    if args.out is not None:
        rows = []
        for result in (episodes[0], episodes[-1]):
            slot = (
                "no slot"
                if result["slot"] is None
                else f"the {SLOT_NAMES[result['slot']]} slot at step {result['step']}"
            )
            rows.append(strip(result["frames"], f"start x = {result['start_x'] * 100:+.0f} cm: {slot}"))
        figure = Image.new("RGB", (max(row.width for row in rows), sum(row.height for row in rows)), "white")
        for index, row in enumerate(rows):
            figure.paste(row, (0, index * rows[0].height))
        args.out.parent.mkdir(parents=True, exist_ok=True)
        figure.save(args.out)
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
