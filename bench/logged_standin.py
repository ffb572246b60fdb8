"""The stand-in robot with its own log of calls and a camera that one process at a time may open, for
bench/robot_faults.py: `bench.logged_standin:LoggedStandIn-v0` (RAQ_ENV_MODULES=bench.logged_standin).

Every call that moves or holds the arm, and each opening and closing of the camera, is a line of the file that
STANDIN_LOG names: "<what> <time.monotonic()> <pid>" (Linux's monotonic clock is the same in every process). The
camera is a lock on "<log>.camera": a second process that makes the env meanwhile gets robot.base.CameraBusy, as
with most USB cameras.
"""

import errno
import fcntl
import os
import time
from pathlib import Path
from typing import TextIO

import gymnasium as gym
import numpy as np

from robot.base import CameraBusy
from robot.standin import PusherStandIn

LOG_VARIABLE = "STANDIN_LOG"
ENV_ID = "bench.logged_standin:LoggedStandIn-v0"
MOVES = ("action", "reset", "hold")
"""The log's words for a call that moves or holds the arm."""


def open_exclusive_camera(lock_path: str) -> TextIO:
    """The camera's lock, held while the returned file is open; CameraBusy while another process holds it."""
    lock = open(lock_path, "a")  # noqa: SIM115 - held open while the camera is
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.close()
        raise CameraBusy(errno.EBUSY, "the camera is open in another process: device busy") from None
    return lock


def record_call(log: str, what: str, value: float | None = None) -> None:
    """One line of the log: "<what> <time.monotonic() or value> <pid>"."""
    with open(log, "a") as file:
        file.write(f"{what} {time.monotonic() if value is None else value!r} {os.getpid()}\n")


class LoggedStandIn(PusherStandIn):
    def __init__(self, **kwargs: object) -> None:
        self.log = os.environ[LOG_VARIABLE]
        self.camera_lock = open_exclusive_camera(f"{self.log}.camera")
        super().__init__(**kwargs)  # type: ignore[arg-type]
        self._record("open")

    def _record(self, what: str) -> None:
        record_call(self.log, what)

    def send_action(self, action: np.ndarray) -> None:
        self._record("action")
        super().send_action(action)

    def reset_scene(self) -> None:
        self._record("reset")
        super().reset_scene()

    def hold_safe(self) -> None:
        self._record("hold")
        super().hold_safe()

    def close(self) -> None:
        super().close()
        if not self.camera_lock.closed:
            self._record("close")
            self.camera_lock.close()


def calls(log: Path) -> list[tuple[str, float, int]]:
    """The log's calls in order: (what, monotonic time, process id)."""
    if not log.exists():
        return []
    lines = log.read_text().split("\n")[:-1]  # (a line still being written has no newline yet)
    return [(what, float(at), int(pid)) for what, at, pid in (line.split(" ") for line in lines)]


if "LoggedStandIn-v0" not in gym.registry:
    gym.register(id="LoggedStandIn-v0", entry_point="bench.logged_standin:LoggedStandIn", max_episode_steps=100)
