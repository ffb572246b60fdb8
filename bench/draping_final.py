"""Where a learned draping policy leaves the hand and the cloth: why a reward on the end effector does not drape.

    MUJOCO_GL=egl python bench/draping_final.py docs/results/compare/draping-hand_distance-seed0 \
        docs/results/compare/draping-vice_raq-seed0 --out docs/results/draping-final.png

Runs each run's last policy (data/checkpoints/run-*/policy.pt) deterministically for one 100-step episode from
each of the env's resets with seeds 0 to EPISODES - 1 and prints, per run, the mean over those episodes of the
final state: the hand's distance to where it is in a drape (`hand_distance`, what the hand-made reward reads), the
cloth's vertices on the box's top, whether it hangs down the near and the far face, its worst fold, and how many
episodes ended draped. With --out it draws each run's last frame of the episode from seed 0, side by side.
"""

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import gymnasium  # noqa: E402
import numpy as np  # noqa: E402
from PIL import Image  # noqa: E402

import sim  # noqa: E402, F401 - registers the tasks
from bench.bookshelf_slots import policy_file, strip  # noqa: E402

EPISODES = 10
"""Episodes per run, one per reset seed."""


def final_states(run_dir: Path) -> tuple[str, list[dict], np.ndarray]:
    """The run's policy (described), the final info of each episode, and the last frame of the first."""
    from learner.policy import load_policy  # noqa: PLC0415 - torch only here

    path = policy_file(run_dir, ("policy.pt",))  # (what the run ended with, not its best evaluation)
    policy = load_policy(path)
    env = gymnasium.make("VisualDraping-v0", render_mode="rgb_array")
    finals, first_frame = [], None
    for seed in range(EPISODES):
        observation, info = env.reset(seed=seed)
        truncated = False
        while not truncated:
            observation, _, _, truncated, info = env.step(policy.env_action(observation, env))
        finals.append(info)
        if first_frame is None:
            first_frame = env.render()
    assert first_frame is not None
    method = run_dir.name.removeprefix("draping-")
    return f"{method} (step {policy.step})", finals, first_frame


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", type=Path, nargs="+", help="bench/learn.py run directories of the draping")
    parser.add_argument("--out", type=Path, default=None, help="the figure (PNG)")
    args = parser.parse_args()
    print(f"final state of {EPISODES} deterministic episodes per run (means)")
    print("| run | hand to the drape's hand position | vertices on the top | near side hangs | far side hangs "
          "| worst fold | draped |\n| --- | --- | --- | --- | --- | --- | --- |")  # fmt: skip
    rows = []
    for run_dir in args.runs:
        name, finals, frame = final_states(run_dir)
        mean = {key: float(np.mean([info[key] for info in finals])) for key in
                ("hand_distance", "covering", "near_hang", "far_hang", "fold", "success")}  # fmt: skip
        print(
            f"| {name} | {mean['hand_distance'] * 100:.1f} cm | {mean['covering']:.1f} | {mean['near_hang']:.0%} "
            f"| {mean['far_hang']:.0%} | {mean['fold'] * 100:.1f} cm | {round(mean['success'] * EPISODES)} of "
            f"{EPISODES} |"
        )
        rows.append(strip([frame], name))
    if args.out is not None:
        figure = Image.new("RGB", (sum(row.width for row in rows), max(row.height for row in rows)), "white")
        for index, row in enumerate(rows):
            figure.paste(row, (sum(r.width for r in rows[:index]), 0))
        figure.save(args.out)
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
