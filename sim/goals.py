"""Goal examples for the simulated tasks: images of success states, as the paper's 10 goal examples per task.

Pusher: the scene is put straight into a success state (mug on the coaster with a little noise, hand at a varied
place behind it). Bookshelf: the held book is put into either empty slot, at a varied depth and offset, so the
examples show both slots. Door, picker and draping: the scripted controller runs from a seeded reset until it succeeds,
settles at a varied nearby pose (hook still in the handle; ball held at a point near the goal), and the final frame
is taken. Every example is checked to be a success. The goal itself (coaster, 45 degrees, point above the table,
the two slots) is fixed in the model and never modified, so it is identical across examples.

    raq goals --task pusher -n 10 --out DIR [--seed S] [--image-size 48] [--display]
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from PIL import Image

from sim import MAX_EPISODE_STEPS, TASKS
from sim.bookshelf import VisualBookshelfEnv
from sim.draping import VisualDrapingEnv
from sim.picker import VisualPickerEnv
from sim.pusher import VisualPusherEnv
from sim.scripted import scripted_action

# Scripted episodes whose seed fails are skipped; give up after this many attempts per example asked for.
MAX_ATTEMPTS_PER_EXAMPLE = 5
# Scripted steps taken after the first success, before settling at a varied pose.
SCRIPTED_STEPS_AFTER_SUCCESS = 5


@dataclass(frozen=True)
class GoalExample:
    """One success state: `image` at the model's resolution, `display` for a person, and the env's `info`."""

    image: np.ndarray
    display: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)


def pusher_success_state(env: VisualPusherEnv, rng: np.random.Generator) -> None:
    """Mug within 1.5 cm of the coaster's centre, any yaw; hand 0.2-4 cm behind it, on the side it pushed from."""
    goal = env.goal_pos
    offset_radius, offset_angle = rng.uniform(0.0, 0.015), rng.uniform(-np.pi, np.pi)
    mug = goal + offset_radius * np.array([np.cos(offset_angle), np.sin(offset_angle)])
    env.set_mug_pos(mug, yaw=float(rng.uniform(-np.pi, np.pi)))
    bearing = -np.pi / 2 + rng.uniform(-0.9, 0.9)
    gap = env.mug_radius + env.pusher_radius + rng.uniform(0.002, 0.04)
    hand_xy = mug + gap * np.array([np.cos(bearing), np.sin(bearing)])
    env.set_hand_pos(np.array([hand_xy[0], hand_xy[1], env.hand_height]))


def bookshelf_success_state(env: VisualBookshelfEnv, rng: np.random.Generator) -> None:
    """The held book in either empty slot (drawn), up to 1 cm off its centre, its bottom 0-5 cm above the floor."""
    slot = env.slot_x[int(rng.integers(0, len(env.slot_x)))]
    bottom = rng.uniform(0.0005, env.inserted_height - 0.01)
    env.set_hand_pos(np.array([slot + rng.uniform(-0.01, 0.01), env.shelf_y, bottom + env.book_height]))


def _settle_action(env: gymnasium.Env, target: np.ndarray) -> np.ndarray:
    """After a scripted success, move to a nearby pose so goal examples vary: the ball (picker) or hook (door)."""
    task_env = env.unwrapped
    step = task_env.action_scale
    if isinstance(task_env, VisualPickerEnv):
        return np.append(np.clip((target - task_env.ball_pos) / step, -1.0, 1.0), 1.0)
    if isinstance(task_env, VisualDrapingEnv):  # (its actions move the hand in y and z)
        return np.clip((target - task_env.hand_pos)[1:] / step, -1.0, 1.0)
    return np.clip((target - task_env.hand_pos) / step, -1.0, 1.0)


def _scripted_success(env: gymnasium.Env, rng: np.random.Generator) -> bool:
    """Run the scripted controller until it succeeds, then settle at a varied nearby pose; True if still a success.

    Picker: the held ball moves to a random point within 1.5 cm (per axis) of the goal point. Draping: the hand up to
    1 cm nearer or farther and up to 2 cm higher. Door: the hook, still in
    the handle, moves up to 1.5 cm along the bar and 1 cm along the pull (the door follows a little).
    """
    for _ in range(MAX_EPISODE_STEPS):
        _, _, _, _, info = env.step(scripted_action(env))
        if info["success"]:
            break
    else:
        return False
    for _ in range(SCRIPTED_STEPS_AFTER_SUCCESS):  # let the controller finish its approach (door: to 45 degrees)
        env.step(scripted_action(env))
    task_env = env.unwrapped
    if isinstance(task_env, VisualPickerEnv):
        target = task_env.goal_pos + rng.uniform(-0.015, 0.015, size=3)
    elif isinstance(task_env, VisualDrapingEnv):  # the draped cloth's held edge, a little nearer, farther or higher
        target = task_env.hand_pos + np.array([0.0, rng.uniform(-0.01, 0.01), rng.uniform(0.0, 0.02)])
    else:
        # The hook stays in the handle: it slides a little along the bar and in the pull direction.
        target = task_env.hand_pos + np.array([rng.uniform(-0.015, 0.015), rng.uniform(-0.01, 0.01), 0.0])
    for _ in range(int(rng.integers(4, 9))):
        env.step(_settle_action(env, target))
    return bool(task_env.get_info()["success"])


def make_goal_examples(
    task: str, n: int, *, seed: int = 0, image_size: int = 48, display_size: int = 256
) -> list[GoalExample]:
    """`n` distinct success states of `task` (a name of sim.TASKS), reproducible from `seed`."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; choose from {sorted(TASKS)}")
    if n < 0:
        raise ValueError(f"n must be non-negative, got {n}")
    rng = np.random.default_rng(seed)
    env = gymnasium.make(TASKS[task], image_size=image_size, render_size=display_size)
    examples: list[GoalExample] = []
    try:
        for attempt in range(n * MAX_ATTEMPTS_PER_EXAMPLE):
            if len(examples) == n:
                break
            env.reset(seed=seed * 100_003 + attempt)
            task_env = env.unwrapped
            if isinstance(task_env, VisualPusherEnv):
                pusher_success_state(task_env, rng)
            elif isinstance(task_env, VisualBookshelfEnv):
                bookshelf_success_state(task_env, rng)
            elif not _scripted_success(env, rng):
                continue
            info = task_env.get_info()
            if info["success"] != 1.0:
                continue
            examples.append(
                GoalExample(image=task_env.render_image(image_size), display=task_env.render_display(), info=info)
            )
    finally:
        env.close()
    if len(examples) < n:
        raise RuntimeError(f"made only {len(examples)} of {n} {task} goal examples")
    return examples


def write_goal_pngs(
    task: str, n: int, out_dir: str | Path, *, seed: int = 0, image_size: int = 48, display: bool = False
) -> list[Path]:
    """Write `n` goal examples of `task` as PNGs named `{task}_goal_NN.png`; return their paths.

    The images are at the model's resolution (`image_size`), or the 256-pixel display view if `display`.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []
    for index, example in enumerate(make_goal_examples(task, n, seed=seed, image_size=image_size)):
        path = out / f"{task}_goal_{index:02d}.png"
        Image.fromarray(example.display if display else example.image).save(path)
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> int:
    """`raq goals`: render goal example PNGs of a simulated task."""
    parser = argparse.ArgumentParser(prog="raq goals", description="Render goal example PNGs of a simulated task.")
    parser.add_argument("--task", required=True, choices=sorted(TASKS), help="which simulated task")
    parser.add_argument("-n", "--count", type=int, default=10, help="number of goal examples (default 10)")
    parser.add_argument("--out", required=True, type=Path, help="directory to write the PNGs into")
    parser.add_argument("--seed", type=int, default=0, help="seed of the examples (default 0)")
    parser.add_argument("--image-size", type=int, default=48, help="side of the model's images in pixels (default 48)")
    parser.add_argument("--display", action="store_true", help="write the 256-pixel display view instead")
    args = parser.parse_args(argv)
    if args.count < 1:
        parser.error("-n must be at least 1")
    paths = write_goal_pngs(
        args.task, args.count, args.out, seed=args.seed, image_size=args.image_size, display=args.display
    )
    for path in paths:
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
