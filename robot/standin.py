"""The simulated pusher behind the robot contract: a stand-in robot to try the whole robot path without one.

Its camera gives 4:3 frames (the square render with grey bands at the sides), so the crop to the observation is
the one a real camera gets. `make("robot.standin:PusherStandIn-v0")`; 100-step episodes, 5 steps per second when
an actor paces it, and a person's reset before every episode.
"""

from typing import Any

import gymnasium as gym
import numpy as np

from robot.base import RobotEnv
from sim.goals import pusher_success_state
from sim.pusher import VisualPusherEnv

BAND = 128
"""Grey pixels at each side of the camera frame."""


class PusherStandIn(RobotEnv):
    control_hz = 5.0
    needs_person_reset = True

    def __init__(
        self, image_size: int = 84, render_size: int = 256, camera_size: int = 384, render_mode: str = "rgb_array"
    ) -> None:
        """`render_size`: the view stored for a person (the display size); `render_mode`: rgb_array only."""
        if render_mode != "rgb_array":
            raise ValueError("the stand-in robot renders rgb_array only")
        self.sim = VisualPusherEnv(image_size=image_size, render_size=camera_size)
        super().__init__(action_dim=self.sim.action_space.shape[0], image_size=image_size, display_size=render_size)
        self.camera_size = camera_size
        self.held = False
        self._success: bool | None = None

    def read_camera(self) -> np.ndarray:
        square = self.sim.render_image(self.camera_size)
        band = np.full((self.camera_size, self.camera_size // 6, 3), BAND, dtype=np.uint8)  # 4:3 in all
        return np.concatenate([band, square, band], axis=1)

    def send_action(self, action: np.ndarray) -> None:
        _, _, _, _, info = self.sim.step(action)
        self._success = bool(info["success"])
        self.held = False

    def reset_scene(self) -> None:
        self.sim.reset(seed=int(self.np_random.integers(2**31)))
        self._success = bool(self.sim.get_info()["success"])

    def hold_safe(self) -> None:
        self.held = True

    def read_success(self) -> bool | None:
        return self._success

    def ground_truth(self) -> dict[str, Any]:
        return self.sim.get_info()

    def close(self) -> None:
        super().close()
        self.sim.close()


def goal_photos(count: int, *, seed: int = 0, camera_size: int = 384) -> list[np.ndarray]:
    """`count` camera frames of success states (the mug on the coaster, the hand near it), reproducible from `seed`:
    the goal photos a person takes with the stand-in's own camera, as a lab takes them with its robot's."""
    rng = np.random.default_rng(seed)
    robot = PusherStandIn(camera_size=camera_size)
    try:
        frames: list[np.ndarray] = []
        for attempt in range(5 * count):
            if len(frames) == count:
                return frames
            robot.sim.reset(seed=seed * 100_003 + attempt)
            pusher_success_state(robot.sim, rng)
            if robot.sim.get_info()["success"]:
                frames.append(robot.read_camera())
        raise RuntimeError(f"made only {len(frames)} of {count} goal photos")
    finally:
        robot.close()


if "PusherStandIn-v0" not in gym.registry:
    gym.register(id="PusherStandIn-v0", entry_point="robot.standin:PusherStandIn", max_episode_steps=100)
