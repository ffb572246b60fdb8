"""Visual Door: hook a cabinet door by its handle bar and pull it open to 45 degrees, seen from a fixed camera."""

from __future__ import annotations

from typing import Any, ClassVar

import mujoco
import numpy as np

from sim.base import SawyerMocapEnv


class VisualDoorEnv(SawyerMocapEnv):
    """
    ## Description
    A Sawyer-like end effector carrying a Γ-shaped hook (an arm reaching 6 cm forward, a 6 cm tip hanging from its
    end) moves in front of a cabinet. The cabinet's 40 x 40 cm yellow door is hinged on its right edge (0 to 60
    degrees) and has a 22 cm handle bar held 4 cm out from it. At the hand's far y-limit the hook's tip hangs over the
    slot behind the bar wherever the hand is in x; lowered into the slot and pulled straight back, it opens the door.
    The goal is the door opened to 45 degrees with the hook still in the handle. This is the *Visual Door* task of
    "End-to-End Robotic Reinforcement Learning without Reward Engineering" (Singh et al., 2019), built after the
    original code's door-hook scene (workspace, start, handle, hook, hinge range, door start and time per step); the
    policy sees only the camera image.

    ## Action Space
    `Box(-1, 1, (3,), float32)`: the desired displacement (dx, dy, dz) of the hook's tip, 2 cm per unit, applied to
    a mocap target that the hand follows, clipped to the workspace x in [-0.11, 0.04], y in [-0.166, 0.184],
    z in [0.10, 0.40] (metres: 15 x 35 x 30 cm, the original's).

    | Num | Action                           | Min | Max | Unit          |
    |-----|----------------------------------|-----|-----|---------------|
    | 0   | displacement of the hand along x | -1  | 1   | 2 cm per unit |
    | 1   | displacement of the hand along y | -1  | 1   | 2 cm per unit |
    | 2   | displacement of the hand along z | -1  | 1   | 2 cm per unit |

    One env step is 0.15 s of simulated time (30 physics steps of 5 ms), as in the original.

    ## Observation Space
    `Box(0, 255, (image_size, image_size, 3), uint8)`: an RGB image from the fixed camera `task_camera`, a side view
    from beyond the door's free edge at -60 degrees elevation (fovy 45), from which the gap between the opening door
    and the dark cabinet is plain. Nothing else is observed.

    ## Rewards / success
    `info["success"]` is 1.0 when the door's hinge angle is within 0.1 rad (`angle_tolerance`, inclusive) of 45
    degrees (`target_angle`), else 0.0. The reward returned by `step` is that sparse flag; learned-reward methods
    replace it. `info` also holds `door_angle` (rad), `door_angle_error` (|angle - 45 deg|, rad), `handle_pos`
    (x, y, z of the middle of the slot behind the handle bar), `hand_pos` (x, y, z of the hook's tip) and `hooked`
    (1.0 when the tip is in the slot behind the bar, below its top).

    ## Starting State
    The hand starts at the fixed point (-0.05, -0.166, 0.40): over the handle in x, nearest the robot, highest. The
    door is closed with probability 0.5, else open at an angle ~ U(0, 0.3 rad), at rest; drawn from
    `self.np_random`.

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
    frame_skip: ClassVar[int] = 30
    hand_low: ClassVar[tuple[float, float, float]] = (-0.11, -0.166, 0.10)
    hand_high: ClassVar[tuple[float, float, float]] = (0.04, 0.184, 0.40)
    hand_init: ClassVar[tuple[float, float, float]] = (-0.05, -0.166, 0.40)
    target_angle: ClassVar[float] = np.pi / 4
    angle_tolerance: ClassVar[float] = 0.1
    max_start_angle: ClassVar[float] = 0.3
    closed_probability: ClassVar[float] = 0.5

    def __init__(self, image_size: int = 48, render_mode: str | None = None, render_size: int = 256) -> None:
        super().__init__(image_size=image_size, render_mode=render_mode, render_size=render_size)
        hinge = self.model.joint("door_hinge")
        self._door_qpos = int(hinge.qposadr[0])
        self._door_qvel = int(hinge.dofadr[0])
        self._door_body = self.model.body("door").id
        self._handle_site = self.model.site("handle_gap").id
        bar = self.model.geom("handle_bar")
        # The slot behind the bar in the door's frame: its height, its depth (local y) and its extent along the door.
        self._slot_z = float(self.model.site_pos[self._handle_site, 2])
        self._slot_y = float(self.model.site_pos[self._handle_site, 1])
        self._bar_radius = float(bar.size[0])
        stub_half_width = float(self.model.geom("handle_stub_free").size[0])
        ends = [-float(self.model.geom(name).pos[0]) for name in ("handle_stub_hinge", "handle_stub_free")]
        self._slot_span = (ends[0] + stub_half_width, ends[1] - stub_half_width)

    @property
    def door_angle(self) -> float:
        """Hinge angle in radians: 0 is closed, positive is open towards the robot."""
        return float(self.data.qpos[self._door_qpos])

    @property
    def handle_pos(self) -> np.ndarray:
        """World position of the middle of the slot between the handle bar and the door."""
        return self.data.site_xpos[self._handle_site].copy()

    def slot_point(self, angle: float, along: float) -> np.ndarray:
        """World position of the point of the slot `along` metres from the hinge, with the door at `angle` radians."""
        hinge = self.model.body_pos[self._door_body]
        c, s = np.cos(angle), np.sin(angle)
        local_x, local_y = -along, self._slot_y
        return hinge + np.array([c * local_x - s * local_y, s * local_x + c * local_y, self._slot_z])

    def slot_along(self, point: np.ndarray, angle: float | None = None) -> tuple[float, float]:
        """(distance from the hinge along the door, distance out from the slot's centre line) of `point`."""
        angle = self.door_angle if angle is None else angle
        offset = np.asarray(point)[:2] - self.model.body_pos[self._door_body][:2]
        c, s = np.cos(angle), np.sin(angle)
        local_x, local_y = c * offset[0] + s * offset[1], -s * offset[0] + c * offset[1]
        return -local_x, self._slot_y - local_y

    def is_hooked(self) -> bool:
        """Whether the hook's tip hangs in the slot behind the handle bar, below the bar's top."""
        along, out = self.slot_along(self.hand_pos)
        inside = self._slot_span[0] <= along <= self._slot_span[1]
        return bool(inside and abs(out) < 0.016 and self.hand_pos[2] < self._slot_z + self._bar_radius)

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
            "hooked": float(self.is_hooked()),
        }
