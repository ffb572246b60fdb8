"""An arm driven through LeRobot (SO-100/101, Koch) behind the robot contract, in a few lines. LeRobot is not a
dependency: `robot` is a connected-or-not lerobot Robot made by the caller."""

from typing import Any

import numpy as np

from robot.base import RobotEnv


class SO101(RobotEnv):
    def __init__(
        self, robot: Any, camera: str = "front",
        joints: tuple[str, ...] = ("shoulder_pan.pos", "elbow_flex.pos", "wrist_flex.pos"),
    ) -> None:  # fmt: skip
        super().__init__(action_dim=len(joints), image_size=84)
        self.robot, self.camera, self.joints = robot, camera, joints
        self.robot.connect()

    def read_camera(self) -> np.ndarray:
        return self.robot.get_observation()[self.camera]

    def send_action(self, action: np.ndarray) -> None:  # 2 degrees per step at most
        now = self.robot.get_observation()
        self.robot.send_action({j: now[j] + 2.0 * float(a) for j, a in zip(self.joints, action, strict=True)})

    def reset_scene(self) -> None:
        self.robot.send_action({j: 0.0 for j in self.joints})

    def hold_safe(self) -> None:  # hold where it is
        self.robot.send_action({j: v for j, v in self.robot.get_observation().items() if j in self.joints})
