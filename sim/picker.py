"""Visual Picker: pick up a tennis ball and hold it 20 cm above the table, seen from a fixed camera."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import mujoco
import numpy as np

from sim.base import SawyerMocapEnv, _contiguous


class VisualPickerEnv(SawyerMocapEnv):
    """
    ## Description
    A Sawyer-like end effector with a two-finger parallel gripper moves freely above a table on which a tennis ball
    lies. The goal is to grasp the ball and hold it at a fixed point 20 cm above the table. This is the *Visual
    Picker* task of "End-to-End Robotic Reinforcement Learning without Reward Engineering" (Singh et al., 2019);
    the policy sees only the camera image.

    ## Action Space
    `Box(-1, 1, (4,), float32)`: the desired displacement (dx, dy, dz) of the point between the fingertips, 2 cm per
    unit, applied to a mocap target that the hand follows and clipped to the workspace x in [-0.15, 0.15],
    y in [-0.15, 0.15], z in [0.025, 0.3] (metres); and the gripper command.

    | Num | Action                           | Min | Max | Unit                                  |
    |-----|----------------------------------|-----|-----|---------------------------------------|
    | 0   | displacement of the hand along x | -1  | 1   | 2 cm per unit                         |
    | 1   | displacement of the hand along y | -1  | 1   | 2 cm per unit                         |
    | 2   | displacement of the hand along z | -1  | 1   | 2 cm per unit                         |
    | 3   | gripper                          | -1  | 1   | -1 fully open ... 1 fully closed      |

    The gripper command sets the fingers' position targets; the fingers squeeze with a limited force, so a closed
    command on the ball holds it.

    ## Observation Space
    `Box(0, 255, (image_size, image_size, 3), uint8)`: an RGB image from the fixed camera `task_camera`, looking at
    the table from the front at -38 degrees elevation. Nothing else is observed.

    ## Rewards / success
    `info["success"]` is 1.0 when the ball's centre is within 3 cm (`success_radius`, inclusive) of the goal point
    (0, 0, 0.2), 20 cm above the table, else 0.0. The reward returned by `step` is that sparse flag;
    learned-reward methods replace it. `info` also holds `ball_to_goal` (m), `ball_pos` (x, y, z), `goal_pos`
    (x, y, z), `hand_pos` (x, y, z) and `gripper_opening` (m between the fingers' inner faces).

    ## Starting State
    The hand starts open at the fixed point (0, -0.08, 0.16). The ball starts at rest on the table with its centre
    at x, y ~ U[-0.05, 0.05] (a 10 x 10 cm square), drawn from `self.np_random`.

    ## Episode End
    There is no terminal state: the episode is truncated after 100 steps by the registered `max_episode_steps`.

    ## Arguments
    `gymnasium.make("VisualPicker-v0", image_size=48, render_mode=None, render_size=256)`

    | Parameter     | Default | Description                                                       |
    |---------------|---------|-------------------------------------------------------------------|
    | `image_size`  | 48      | side of the square observation image in pixels                    |
    | `render_mode` | None    | `"rgb_array"` makes `render()` return the display view             |
    | `render_size` | 256     | side of the display view returned by `render()` in pixels         |
    """

    xml_file: ClassVar[str] = "picker.xml"
    action_dim: ClassVar[int] = 4
    hand_low: ClassVar[tuple[float, float, float]] = (-0.15, -0.15, 0.025)
    hand_high: ClassVar[tuple[float, float, float]] = (0.15, 0.15, 0.3)
    hand_init: ClassVar[tuple[float, float, float]] = (0.0, -0.08, 0.16)
    ball_radius: ClassVar[float] = 0.03
    ball_half_range: ClassVar[float] = 0.05
    success_radius: ClassVar[float] = 0.03

    def __init__(self, image_size: int = 48, render_mode: str | None = None, render_size: int = 256) -> None:
        super().__init__(image_size=image_size, render_mode=render_mode, render_size=render_size)
        ball_joint = self.model.joint("ball_free")
        self._ball_qpos = int(ball_joint.qposadr[0])
        self._ball_qvel = int(ball_joint.dofadr[0])
        self._ball_body = self.model.body("ball").id
        # The goal point is a static site: read once from the model and never written to.
        mujoco.mj_forward(self.model, self.data)
        self._goal_pos = self.data.site_xpos[self.model.site("goal").id].copy()
        self._goal_pos.flags.writeable = False
        self._finger_qpos = _contiguous([self.model.joint(n).qposadr[0] for n in ("left_finger", "right_finger")])
        self._finger_actuators = _contiguous([self.model.actuator(n).id for n in ("left_finger", "right_finger")])
        self._finger_travel = float(self.model.actuator_ctrlrange[self.model.actuator("left_finger").id, 1])
        self._finger_offset = float(abs(self.model.body_pos[self.model.body("left_finger").id, 0]))
        self._finger_half_width = float(self.model.geom_size[self.model.geom("left_finger").id, 0])

    @property
    def goal_pos(self) -> np.ndarray:
        """The fixed point 20 cm above the table where the ball should be held."""
        return self._goal_pos.copy()

    @property
    def ball_pos(self) -> np.ndarray:
        """World position of the ball's centre."""
        return self.data.xpos[self._ball_body].copy()

    @property
    def gripper_opening(self) -> float:
        """Distance in metres between the fingers' inner faces."""
        left, right = self.data.qpos[self._finger_qpos]
        return 2.0 * (self._finger_offset - self._finger_half_width) - float(left + right)

    def set_ball_pos(self, pos: np.ndarray) -> None:
        """Put the ball at rest at `pos` (no rotation)."""
        adr = self._ball_qpos
        self.data.qpos[adr : adr + 3] = np.asarray(pos, dtype=np.float64)
        self.data.qpos[adr + 3 : adr + 7] = (1.0, 0.0, 0.0, 0.0)
        self.data.qvel[self._ball_qvel : self._ball_qvel + 6] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def _reset_task(self) -> None:
        xy = self.np_random.uniform(-self.ball_half_range, self.ball_half_range, size=2)
        self.set_ball_pos(np.array([xy[0], xy[1], self.ball_radius]))

    def _apply_action(self, action: np.ndarray) -> None:
        self._move_hand(action[:3])
        self.data.ctrl[self._finger_actuators] = 0.5 * (action[3] + 1.0) * self._finger_travel

    def get_info(self) -> dict[str, Any]:
        ball = self.ball_pos
        ball_to_goal = math.dist(ball, self._goal_pos)
        return {
            "success": float(ball_to_goal <= self.success_radius),
            "ball_to_goal": ball_to_goal,
            "ball_pos": ball,
            "goal_pos": self._goal_pos.copy(),
            "hand_pos": self.hand_pos,
            "gripper_opening": self.gripper_opening,
        }
