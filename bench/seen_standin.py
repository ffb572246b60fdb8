"""The stand-in robot as a person at the robot sees it, for the automated person of bench/robot_standin.py: after
every action and reset it writes where the mug, the coaster and the hand are (the sim's ground truth, what a person
sees by looking) to the file that STANDIN_SEEN names, as JSON: {"mug", "goal", "hand", "success", "episode",
"step"}. `bench.seen_standin:SeenStandIn-v0` (RAQ_ENV_MODULES=bench.seen_standin); otherwise the stand-in itself.
"""

import json
import os
from pathlib import Path

import gymnasium as gym
import numpy as np

from robot.standin import PusherStandIn

SEEN_VARIABLE = "STANDIN_SEEN"
ENV_ID = "bench.seen_standin:SeenStandIn-v0"


class SeenStandIn(PusherStandIn):
    def __init__(self, **kwargs: object) -> None:
        super().__init__(**kwargs)  # type: ignore[arg-type]
        self.seen = Path(os.environ[SEEN_VARIABLE])
        self.episode, self.episode_step = 0, 0

    def send_action(self, action: np.ndarray) -> None:
        super().send_action(action)
        self.episode_step += 1
        self._tell()

    def reset_scene(self) -> None:
        super().reset_scene()
        self.episode, self.episode_step = self.episode + 1, 0
        self._tell()

    def _tell(self) -> None:
        sim = self.sim
        state = {
            "mug": sim.mug_pos.tolist(), "goal": sim.goal_pos.tolist(), "hand": sim.hand_pos[:2].tolist(),
            "success": bool(self._success), "episode": self.episode, "step": self.episode_step,
        }  # fmt: skip
        partial = self.seen.with_suffix(".partial")
        partial.write_text(json.dumps(state))
        partial.replace(self.seen)  # (whole, or the previous one: never half a file)


def seen_state(path: Path) -> dict | None:
    """What the stand-in last told (None before its first reset)."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


if "SeenStandIn-v0" not in gym.registry:
    gym.register(id="SeenStandIn-v0", entry_point="bench.seen_standin:SeenStandIn", max_episode_steps=100)
