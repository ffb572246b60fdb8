"""Visual Pusher: push a mug onto a coaster, seen from a fixed camera."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import mujoco
import numpy as np

from sim.base import SawyerMocapEnv


class VisualPusherEnv(SawyerMocapEnv):
    """
    ## Description
    A Sawyer-like end effector with a cylindrical pusher moves in a horizontal plane above a table. The goal is to
    push a red mug onto a blue coaster. The coaster is fixed; the mug starts at a random place between the pusher
    and the coaster. This is the *Visual Pusher* task of "End-to-End Robotic Reinforcement Learning without Reward
    Engineering" (Singh et al., 2019); the policy sees only the camera image.

    ## Action Space
    `Box(-1, 1, (2,), float32)`: the desired displacement (dx, dy) of the end effector, 2 cm per unit, applied to a
    mocap target that the hand follows. The hand height is fixed and the target is clipped to the workspace
    x in [-0.16, 0.16], y in [-0.18, 0.22] (metres).

    | Num | Action                          | Min | Max | Unit              |
    |-----|---------------------------------|-----|-----|-------------------|
    | 0   | displacement of the hand along x | -1  | 1   | 2 cm per unit     |
    | 1   | displacement of the hand along y | -1  | 1   | 2 cm per unit     |

    ## Observation Space
    `Box(0, 255, (image_size, image_size, 3), uint8)`: an RGB image from the fixed camera `task_camera`, looking
    down at the table at -60 degrees elevation. Nothing else (no joint angles, no positions) is observed.

    ## Rewards / success
    `info["success"]` is 1.0 when the mug's centre is within 3 cm (`success_radius`, inclusive) of the coaster's
    centre in the table plane, else 0.0. The reward returned by `step` is that sparse flag; learned-reward methods
    replace it. `info` also holds `mug_to_goal` (m), `mug_pos` (x, y), `goal_pos` (x, y) and `hand_pos` (x, y, z).

    ## Starting State
    The hand starts at the fixed point (0, -0.15) at height 3.5 cm. The mug starts at rest at x ~ U[-0.1, 0.1],
    y ~ U[-0.05, 0.1] (a 20 x 15 cm region, 7 to 26 cm short of the coaster at (0, 0.17)) with a random yaw, all
    drawn from `self.np_random`.

    ## Episode End
    There is no terminal state: the episode is truncated after 100 steps by the registered `max_episode_steps`.

    ## Arguments
    `gymnasium.make("VisualPusher-v0", image_size=48, render_mode=None, render_size=256)`

    | Parameter     | Default | Description                                                       |
    |---------------|---------|-------------------------------------------------------------------|
    | `image_size`  | 48      | side of the square observation image in pixels                    |
    | `render_mode` | None    | `"rgb_array"` makes `render()` return the display view             |
    | `render_size` | 256     | side of the display view returned by `render()` in pixels         |
    """

    xml_file: ClassVar[str] = "pusher.xml"
    action_dim: ClassVar[int] = 2
    hand_height: ClassVar[float] = 0.035
    hand_low: ClassVar[tuple[float, float, float]] = (-0.16, -0.18, hand_height)
    hand_high: ClassVar[tuple[float, float, float]] = (0.16, 0.22, hand_height)
    hand_init: ClassVar[tuple[float, float, float]] = (0.0, -0.15, hand_height)
    mug_low: ClassVar[tuple[float, float]] = (-0.1, -0.05)
    mug_high: ClassVar[tuple[float, float]] = (0.1, 0.1)
    mug_radius: ClassVar[float] = 0.035
    pusher_radius: ClassVar[float] = 0.018
    success_radius: ClassVar[float] = 0.03

    def __init__(self, image_size: int = 48, render_mode: str | None = None, render_size: int = 256) -> None:
        super().__init__(image_size=image_size, render_mode=render_mode, render_size=render_size)
        self._mug_qpos = np.array([self.model.joint(name).qposadr[0] for name in ("mug_x", "mug_y", "mug_yaw")])
        self._mug_qvel = np.array([self.model.joint(name).dofadr[0] for name in ("mug_x", "mug_y", "mug_yaw")])
        self._mug_body = self.model.body("mug").id
        # The coaster is static: its centre is read once from the model and never written to.
        mujoco.mj_forward(self.model, self.data)
        self._goal_xy = self.data.site_xpos[self.model.site("goal").id, :2].copy()
        self._goal_xy.flags.writeable = False

    @property
    def goal_pos(self) -> np.ndarray:
        """(x, y) of the coaster's centre: fixed for the life of the env."""
        return self._goal_xy.copy()

    @property
    def mug_pos(self) -> np.ndarray:
        """(x, y) of the mug's centre."""
        return self.data.xpos[self._mug_body, :2].copy()

    def set_mug_pos(self, xy: np.ndarray, yaw: float | None = None) -> None:
        """Put the mug at rest at `xy` (and `yaw` radians, if given)."""
        self.data.qpos[self._mug_qpos[:2]] = np.asarray(xy, dtype=np.float64)
        if yaw is not None:
            self.data.qpos[self._mug_qpos[2]] = yaw
        self.data.qvel[self._mug_qvel] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def _reset_task(self) -> None:
        xy = self.np_random.uniform(self.mug_low, self.mug_high)
        self.set_mug_pos(xy, yaw=float(self.np_random.uniform(-np.pi, np.pi)))

    def _apply_action(self, action: np.ndarray) -> None:
        self._move_hand(np.array([action[0], action[1], 0.0]))

    def get_info(self) -> dict[str, Any]:
        mug = self.mug_pos
        mug_to_goal = math.hypot(mug[0] - self._goal_xy[0], mug[1] - self._goal_xy[1])
        return {
            "success": float(mug_to_goal <= self.success_radius),
            "mug_to_goal": mug_to_goal,
            "mug_pos": mug,
            "goal_pos": self._goal_xy.copy(),
            "hand_pos": self.hand_pos,
        }
