"""Visual Door: hook a cabinet door by its handle and pull it open to 45 degrees, seen from a fixed camera."""

from __future__ import annotations

from typing import Any, ClassVar

import mujoco
import numpy as np

from sim.base import SawyerMocapEnv


class VisualDoorEnv(SawyerMocapEnv):
    """
    ## Description
    A Sawyer-like end effector carrying a downward-pointing hook moves freely above a table with a cabinet. The
    cabinet's yellow door is hinged on its left edge and has a pull handle (a bar held out from the door by two
    stubs). To open the door the hook must be dropped into the gap behind the bar and pulled along the door's arc.
    The goal is a door opened to 45 degrees. This is the *Visual Door* task of "End-to-End Robotic Reinforcement
    Learning without Reward Engineering" (Singh et al., 2019); the policy sees only the camera image.

    ## Action Space
    `Box(-1, 1, (3,), float32)`: the desired displacement (dx, dy, dz) of the hook's tip, 2 cm per unit, applied to
    a mocap target that the hand follows, clipped to the workspace x in [-0.25, 0.25], y in [-0.25, 0.02],
    z in [0.06, 0.35] (metres).

    | Num | Action                           | Min | Max | Unit          |
    |-----|----------------------------------|-----|-----|---------------|
    | 0   | displacement of the hand along x | -1  | 1   | 2 cm per unit |
    | 1   | displacement of the hand along y | -1  | 1   | 2 cm per unit |
    | 2   | displacement of the hand along z | -1  | 1   | 2 cm per unit |

    ## Observation Space
    `Box(0, 255, (image_size, image_size, 3), uint8)`: an RGB image from the fixed camera `task_camera`, looking
    down at the cabinet from the front right at -60 degrees elevation. Nothing else is observed.

    ## Rewards / success
    `info["success"]` is 1.0 when the door's hinge angle is within 0.1 rad (`angle_tolerance`, inclusive) of 45
    degrees (`target_angle`), else 0.0. The reward returned by `step` is that sparse flag; learned-reward methods
    replace it. `info` also holds `door_angle` (rad), `door_angle_error` (|angle - 45 deg|, rad), `handle_pos`
    (x, y, z of the gap behind the handle bar) and `hand_pos` (x, y, z of the hook's tip).

    ## Starting State
    The hand starts at the fixed point (0.1, -0.15, 0.3). The door is closed with probability 0.5, else open at an
    angle ~ U(0, 15 degrees), at rest; drawn from `self.np_random`.

    ## Episode End
    There is no terminal state: the episode is truncated after 100 steps by the registered `max_episode_steps`.

    ## Arguments
    `gymnasium.make("VisualDoor-v0", image_size=48, render_mode=None, render_size=256)`

    | Parameter     | Default | Description                                                       |
    |---------------|---------|-------------------------------------------------------------------|
    | `image_size`  | 48      | side of the square observation image in pixels                    |
    | `render_mode` | None    | `"rgb_array"` makes `render()` return the display view             |
    | `render_size` | 256     | side of the display view returned by `render()` in pixels         |
    """

    xml_file: ClassVar[str] = "door.xml"
    action_dim: ClassVar[int] = 3
    hand_low: ClassVar[tuple[float, float, float]] = (-0.25, -0.25, 0.06)
    hand_high: ClassVar[tuple[float, float, float]] = (0.25, 0.02, 0.35)
    hand_init: ClassVar[tuple[float, float, float]] = (0.1, -0.15, 0.3)
    target_angle: ClassVar[float] = np.pi / 4
    angle_tolerance: ClassVar[float] = 0.1
    max_start_angle: ClassVar[float] = np.radians(15.0)
    closed_probability: ClassVar[float] = 0.5

    def __init__(self, image_size: int = 48, render_mode: str | None = None, render_size: int = 256) -> None:
        super().__init__(image_size=image_size, render_mode=render_mode, render_size=render_size)
        hinge = self.model.joint("door_hinge")
        self._door_qpos = int(hinge.qposadr[0])
        self._door_qvel = int(hinge.dofadr[0])
        self._door_body = self.model.body("door").id
        self._handle_site = self.model.site("handle_gap").id

    @property
    def door_angle(self) -> float:
        """Hinge angle in radians: 0 is closed, positive is open towards the robot."""
        return float(self.data.qpos[self._door_qpos])

    @property
    def handle_pos(self) -> np.ndarray:
        """World position of the middle of the gap between the handle bar and the door."""
        return self.data.site_xpos[self._handle_site].copy()

    def handle_pos_at(self, angle: float) -> np.ndarray:
        """Where the handle gap would be with the door at `angle` radians (for scripted controllers)."""
        hinge = self.model.body_pos[self._door_body]
        local = self.model.site_pos[self._handle_site]
        c, s = np.cos(angle), np.sin(angle)
        # Rotation about -z by `angle`.
        return hinge + np.array([c * local[0] + s * local[1], -s * local[0] + c * local[1], local[2]])

    def set_door_angle(self, angle: float) -> None:
        """Put the door at rest at `angle` radians."""
        self.data.qpos[self._door_qpos] = angle
        self.data.qvel[self._door_qvel] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def _reset_task(self) -> None:
        closed = self.np_random.uniform() < self.closed_probability
        self.set_door_angle(0.0 if closed else float(self.np_random.uniform(0.0, self.max_start_angle)))

    def _apply_action(self, action: np.ndarray) -> None:
        self._move_hand(action)

    def get_info(self) -> dict[str, Any]:
        angle = self.door_angle
        error = abs(angle - self.target_angle)
        return {
            "success": float(error <= self.angle_tolerance),
            "door_angle": angle,
            "door_angle_error": error,
            "handle_pos": self.handle_pos,
            "hand_pos": self.hand_pos,
        }
