"""A robot env to copy: put this file beside your code (say my_lab/arm.py), fill in the marked parts, allow the
module (RAQ_ENV_MODULES=my_lab.arm), start the robot's own process (`raq robot my_lab.arm:MyArm-v0`, or
RAQ_ROBOTS=my_lab.arm:MyArm-v0 for `raq up`) and start a run on the env "my_lab.arm:MyArm-v0".

What each part must do is in robot/base.py. Keep the safety limits here, in the env: the learner only ever sends
actions in [-1, 1], and `limit_action` is the last word before the arm moves. Only `send_action`, `reset_scene`
and `hold_safe` may move or hold the arm: `__init__` connects and never moves it, and `read_camera` only reads (the
robot's own process makes this env once and reads the camera between runs for the pages; no other process opens
it while that process is up).
"""

import gymnasium as gym
import numpy as np

from robot.base import RobotEnv
from robot.camera import OpenCVCamera

STEP_M = 0.01
"""Metres the hand moves per control period at action 1 (fill in: your arm's safe step)."""
TOP_SPEED_M_S = 0.05
"""The hand's top speed in metres per second (fill in): no step moves it faster over the time it was given."""
WORKSPACE_LOW = np.array([-0.20, -0.20, 0.02])
WORKSPACE_HIGH = np.array([0.20, 0.20, 0.25])
"""The box the hand must stay in, in metres, in the arm's base frame (fill in)."""


class MyArmEnv(RobotEnv):
    control_hz = 5.0
    needs_person_reset = True

    def __init__(self, image_size: int = 84, camera: int | str = 0) -> None:
        super().__init__(action_dim=3, image_size=image_size)
        self.camera = OpenCVCamera(camera)  # (CameraBusy while another process has it: the actor tries again)
        self.hand = np.zeros(3)  # fill in: read the hand's position from your arm's driver (connect; never move)

    def read_camera(self) -> np.ndarray:
        return self.camera.read()

    def limit_action(self, action: np.ndarray, *, seconds: float | None = None) -> np.ndarray:
        """No step leaves the workspace box or moves the hand faster than TOP_SPEED_M_S over `seconds`, the time
        since the previous action (one control period for the first after a reset)."""
        step = STEP_M * action
        if seconds is not None:
            reach = TOP_SPEED_M_S * seconds
            step = np.clip(step, -reach, reach)
        target = np.clip(self.hand + step, WORKSPACE_LOW, WORKSPACE_HIGH)
        return ((target - self.hand) / STEP_M).astype(np.float32)

    def send_action(self, action: np.ndarray) -> None:
        self.hand = self.hand + STEP_M * action
        raise NotImplementedError("fill in: send self.hand to your arm's driver as its next target")

    def reset_scene(self) -> None:
        raise NotImplementedError("fill in: move the arm to its start pose and wait until it is there")

    def hold_safe(self) -> None:
        raise NotImplementedError("fill in: hold the arm where it is (zero velocity, brakes)")

    def close(self) -> None:
        super().close()
        self.camera.close()


gym.register(id="MyArm-v0", entry_point=f"{__name__}:MyArmEnv", max_episode_steps=50)
