"""A robot for the watchdog's tests: DotReach's dot behind the robot contract (robot.base.RobotEnv), which writes every
action it sends, every reset and every hold to a log with its time.

The log is the file that RECORDING_ARM_LOG names (nothing is written without it), one line per event:
"<what> <time.monotonic()> <pid>", so a test reads, from its own process, when the actor's arm moved and when it
was held, and by which process (Linux's monotonic clock is the same in every process); "limit <seconds>" lines say
what `limit_action` was told, "sent <number>" lines the first number of each action sent.
`make("recording_arm:RecordingArm-v0")` with RAQ_ENV_MODULES listing `recording_arm` and this folder on the path.
`LateArm-v0` is the same arm whose every LATE_EVERY-th action takes 1.3 control periods to send; `ExclusiveArm-v0`
one whose camera opens in one process at a time (robot.base's CameraBusy for a second), as most USB cameras do;
`JammingArm-v0` one whose JAM_AT-th action raises; `FactoryArm-v0` the recording arm registered through a factory
function (`make_arm`), as a lab that wraps its driver might register it: its registration cannot say that it is a
robot.
"""

import os
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

from bench.logged_standin import calls as recorded_by
from bench.logged_standin import open_exclusive_camera, record_call
from learner.testing_envs import DotReach
from robot.base import RobotEnv

LOG_VARIABLE = "RECORDING_ARM_LOG"
ENV_ID = "recording_arm:RecordingArm-v0"
LATE_ENV_ID = "recording_arm:LateArm-v0"
EXCLUSIVE_ENV_ID = "recording_arm:ExclusiveArm-v0"
JAMMING_ENV_ID = "recording_arm:JammingArm-v0"
FACTORY_ENV_ID = "recording_arm:FactoryArm-v0"
LATE_EVERY = 5
JAM_AT = 20


class RecordingArm(RobotEnv):
    control_hz = 10.0
    needs_person_reset = False

    def __init__(self, image_size: int = 16, render_size: int = 32, render_mode: str = "rgb_array") -> None:
        super().__init__(action_dim=2, image_size=image_size, display_size=render_size)
        self.dot = DotReach(obs_size=image_size, render_size=render_size)
        self.log = os.environ.get(LOG_VARIABLE)

    def _record(self, what: str, value: float | None = None) -> None:
        if self.log:
            record_call(self.log, what, value)

    def limit_action(self, action: np.ndarray, *, seconds: float | None = None) -> np.ndarray:
        self._record("limit", float("nan") if seconds is None else seconds)
        return action

    def read_camera(self) -> np.ndarray:
        return self.dot._draw(48)

    def send_action(self, action: np.ndarray) -> None:
        self._record("action")
        self._record("sent", float(action[0]))  # (its first number: whose action it was)
        self.dot.step(action)

    def reset_scene(self) -> None:
        self.dot.reset(seed=int(self.np_random.integers(2**31)))
        self._record("reset")

    def hold_safe(self) -> None:
        self._record("hold")


class LateArm(RecordingArm):
    """The recording arm whose every LATE_EVERY-th action takes 1.3 control periods to send (a slow driver)."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__(**kwargs)  # type: ignore[arg-type]
        self.sent = 0

    def send_action(self, action: np.ndarray) -> None:
        super().send_action(action)
        self.sent += 1
        if self.sent % LATE_EVERY == 0:
            time.sleep(1.3 / self.control_hz)


class ExclusiveArm(RecordingArm):
    """The recording arm whose camera one process at a time may have open (a lock on the log's ".camera" file):
    making it in a second process raises CameraBusy until the first closes it."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__(**kwargs)  # type: ignore[arg-type]
        self.camera = open_exclusive_camera(f"{self.log}.camera")
        self._record("open")

    def close(self) -> None:
        super().close()
        if not self.camera.closed:
            self._record("close")
            self.camera.close()


class JammingArm(RecordingArm):
    """The recording arm whose gripper jams at its JAM_AT-th action (send_action raises)."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__(**kwargs)  # type: ignore[arg-type]
        self.sent = 0

    def send_action(self, action: np.ndarray) -> None:
        self.sent += 1
        if self.sent == JAM_AT:
            raise RuntimeError("the gripper jammed")
        super().send_action(action)


def make_arm(**kwargs: object) -> RecordingArm:
    """The recording arm, made by a function (FactoryArm-v0's entry point)."""
    return RecordingArm(**kwargs)  # type: ignore[arg-type]


def recorded(log: Path) -> list[tuple[str, float]]:
    """The log's events in order: (what, monotonic time)."""
    return [(what, at) for what, at, _ in recorded_by(log)]


if "RecordingArm-v0" not in gym.registry:
    gym.register(id="RecordingArm-v0", entry_point="recording_arm:RecordingArm", max_episode_steps=1000)
    gym.register(id="LateArm-v0", entry_point="recording_arm:LateArm", max_episode_steps=1000)
    gym.register(id="ExclusiveArm-v0", entry_point="recording_arm:ExclusiveArm", max_episode_steps=1000)
    gym.register(id="JammingArm-v0", entry_point="recording_arm:JammingArm", max_episode_steps=1000)
    gym.register(id="FactoryArm-v0", entry_point=make_arm, max_episode_steps=1000)
