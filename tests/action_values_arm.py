"""The recording arm (tests/recording_arm.py) that also writes the values of every action it sends, so that a test
can find each of the arm's actions among a learner's transitions.

The file that ACTIONS_VARIABLE names (nothing is written without it) has one line per action:
"<time.monotonic()> <value> <value> …". `make("action_values_arm:ActionValuesArm-v0")` with RAQ_ENV_MODULES listing
`recording_arm,action_values_arm` and this folder on the path.
"""

import os
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
from recording_arm import RecordingArm

ACTIONS_VARIABLE = "ACTION_VALUES_ARM_LOG"
ENV_ID = "action_values_arm:ActionValuesArm-v0"


class ActionValuesArm(RecordingArm):
    def send_action(self, action: np.ndarray) -> None:
        super().send_action(action)
        path = os.environ.get(ACTIONS_VARIABLE)
        if path:
            with open(path, "a") as file:
                file.write(" ".join(repr(float(value)) for value in (time.monotonic(), *action)) + "\n")


def actions_sent(path: Path, *, before: float) -> np.ndarray:
    """The values of the actions the arm sent before the monotonic time `before`, in order, one row each."""
    lines = path.read_text().split("\n")[:-1] if path.exists() else []  # (a line being written has no newline)
    rows = [[float(value) for value in line.split(" ")] for line in lines]
    return np.asarray([row[1:] for row in rows if row[0] < before], dtype=np.float64)


if "ActionValuesArm-v0" not in gym.registry:
    gym.register(id="ActionValuesArm-v0", entry_point="action_values_arm:ActionValuesArm", max_episode_steps=1000)
