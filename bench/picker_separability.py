"""Can f_psi tell the picker's success states from the near misses its policy exploits, at 48 px?

    MUJOCO_GL=egl python bench/picker_separability.py [--examples 300] [--steps 300]

Renders the picker with the ball held (hand and ball together) at random success positions (within 3 cm of the
goal point) and at the near misses VICE-RAQ's policy settled on (4.5-6.5 cm toward the camera, near the goal's
height, where the image differs from the goal view mostly in scale), trains a plain f_psi (the run's network,
sigmoid cross-entropy with mixup, the default schedule's lr) on two thirds of each, and prints the held-out
accuracy on both classes every 100 steps. High accuracy means the success is observable from this camera and
a classifier given such negatives can learn it.
"""

import argparse
import os
import sys
from pathlib import Path

import gymnasium
import mujoco
import numpy as np
import torch

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from contract.config import TrainConfig  # noqa: E402
from learner.reward import RewardModel  # noqa: E402
from sim import TASKS  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--examples", type=int, default=300, help="renders per class")
    parser.add_argument("--steps", type=int, default=300, help="classifier steps")
    args = parser.parse_args()
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    env = gymnasium.make(TASKS["picker"]).unwrapped
    env.reset(seed=0)
    goal = env.goal_pos

    def held_at(position: np.ndarray) -> np.ndarray:
        env.set_ball_pos(position)
        env.set_hand_pos(position)
        mujoco.mj_forward(env.model, env.data)
        return env.render_image(48)

    def success() -> np.ndarray:
        while True:
            offset = rng.uniform(-0.03, 0.03, 3)
            if np.linalg.norm(offset) <= 0.03:
                return goal + offset

    def near_miss() -> np.ndarray:
        return goal + np.array([rng.uniform(0.045, 0.065), rng.uniform(-0.01, 0.01), rng.uniform(-0.01, 0.03)])

    positives = np.stack([held_at(success()) for _ in range(args.examples)])
    negatives = np.stack([held_at(near_miss()) for _ in range(args.examples)])
    env.close()
    train = 2 * args.examples // 3
    model = RewardModel.for_run(TrainConfig(algorithm="raq", precision="fp32"), rng)
    for step in range(1, args.steps + 1):
        picks = rng.integers(0, train, size=(2, 128))
        model.update_classifier(positives[picks[0]], negatives[picks[1]], accuracy=False)
        if step % 100 == 0 or step == args.steps:
            held_pos, held_neg = model.logits(positives[train:]), model.logits(negatives[train:])
            print(
                f"step {step}: held-out accuracy, success {np.mean(held_pos > 0):.2f}, near miss "
                f"{np.mean(held_neg < 0):.2f}; mean f_psi {held_pos.mean():+.2f} / {held_neg.mean():+.2f}",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
