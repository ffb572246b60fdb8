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
    A Sawyer-like end effector with a two-finger parallel gripper works above a 10 x 10 cm region of a table in which
    a tennis ball lies. The goal is to grasp the ball and hold it at a fixed point 20 cm above the table's centre.
    This is the *Visual Picker* task of "End-to-End Robotic Reinforcement Learning without Reward Engineering"
    (Singh et al., 2019), built after the original code's pick-and-place scene: the hand's xy-range is the ball's
    region, the hand starts above its centre, and the ball slides without rolling and is kept inside the region
    while on the table (the original zeroed the object's velocity each step and clamped it into the region), so it
    never leaves the hand's reach. The policy sees only the camera image.

    ## Action Space
    `Box(-1, 1, (4,), float32)`: the desired displacement (dx, dy, dz) of the point between the fingertips, 2 cm per
    unit, applied to a mocap target that the hand follows and clipped to the workspace x in [-0.05, 0.05],
    y in [-0.05, 0.05], z in [0.03, 0.27] (metres: 10 x 10 x 24 cm, the original's); and the gripper command.

    | Num | Action                           | Min | Max | Unit                                  |
    |-----|----------------------------------|-----|-----|---------------------------------------|
    | 0   | displacement of the hand along x | -1  | 1   | 2 cm per unit                         |
    | 1   | displacement of the hand along y | -1  | 1   | 2 cm per unit                         |
    | 2   | displacement of the hand along z | -1  | 1   | 2 cm per unit                         |
    | 3   | gripper                          | -1  | 1   | -1 fully open ... 1 fully closed      |

    The gripper command sets the fingers' position targets (open, their inner faces are 9 cm apart; the ball is
    6 cm across); the fingers squeeze with a limited force, so a closed command on the ball holds it. One env step
    is 0.1 s of simulated time (20 physics steps of 5 ms), as in the original.

    ## Observation Space
    `Box(0, 255, (image_size, image_size, 3), uint8)`: an RGB image from the fixed camera `task_camera`, looking at
    the table from the side (+x) at -38 degrees elevation. Nothing else is observed.

    ## Rewards / success
    `info["success"]` is 1.0 when the ball's centre is within 3 cm (`success_radius`, inclusive) of the goal point
    (0, 0, 0.2), 20 cm above the table, else 0.0. The reward returned by `step` is that sparse flag;
    learned-reward methods replace it. `info` also holds `ball_to_goal` (m), `ball_pos` (x, y, z), `goal_pos`
    (x, y, z), `hand_pos` (x, y, z) and `gripper_opening` (m between the fingers' inner faces).

    ## Starting State
    The hand starts open at the fixed point (0, 0, 0.2), above the centre of the ball's region. The ball starts at
    rest on the table with its centre at x, y ~ U[-0.05, 0.05] (the 10 x 10 cm region), drawn from
    `self.np_random`. While the ball rests on the table (centre below `resting_height`) its centre is kept inside
    the region and its velocity is zeroed after every step.

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
    frame_skip: ClassVar[int] = 20
    hand_low: ClassVar[tuple[float, float, float]] = (-0.05, -0.05, 0.03)
    hand_high: ClassVar[tuple[float, float, float]] = (0.05, 0.05, 0.27)
    hand_init: ClassVar[tuple[float, float, float]] = (0.0, 0.0, 0.2)
    ball_radius: ClassVar[float] = 0.03
    ball_half_range: ClassVar[float] = 0.05
    # Below this height of its centre the ball counts as resting on the table (kept in its region, stopped).
    resting_height: ClassVar[float] = 0.035
    success_radius: ClassVar[float] = 0.03

    def __init__(self, image_size: int = 48, render_mode: str | None = None, render_size: int = 256) -> None:
        super().__init__(image_size=image_size, render_mode=render_mode, render_size=render_size)
        self._ball_qpos = _contiguous([self.model.joint(f"ball_{axis}").qposadr[0] for axis in "xyz"])
        self._ball_qvel = _contiguous([self.model.joint(f"ball_{axis}").dofadr[0] for axis in "xyz"])
        self._ball_body = self.model.body("ball").id
        self._ball_origin = self.model.body_pos[self._ball_body].copy()
        # The goal point is a static site: read once from the model and never written to.
        mujoco.mj_forward(self.model, self.data)
        self._goal_pos = self.data.site_xpos[self.model.site("goal").id].copy()
        self._goal_pos.flags.writeable = False
        self._finger_qpos = _contiguous([self.model.joint(n).qposadr[0] for n in ("left_finger", "right_finger")])
        self._finger_actuators = _contiguous([self.model.actuator(n).id for n in ("left_finger", "right_finger")])
        self._finger_travel = float(self.model.actuator_ctrlrange[self.model.actuator("left_finger").id, 1])
        self._finger_offset = float(abs(self.model.body_pos[self.model.body("left_finger").id, 1]))
        self._finger_half_width = float(self.model.geom_size[self.model.geom("left_finger").id, 1])

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
        """Put the ball at rest at `pos` (the joints' origin is the table's centre at the ball's resting height)."""
        self.data.qpos[self._ball_qpos] = np.asarray(pos, dtype=np.float64) - self._ball_origin
        self.data.qvel[self._ball_qvel] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = super().step(action)
        ball = self.ball_pos
        if ball[2] < self.resting_height:
            # On the table: stop the ball and keep it in its region, as the original did with its object.
            limit = self.ball_half_range
            clamped = np.clip(ball[:2], -limit, limit)
            self.data.qvel[self._ball_qvel] = 0.0
            if not np.array_equal(clamped, ball[:2]):
                self.set_ball_pos(np.array([clamped[0], clamped[1], ball[2]]))
                observation, info = self._observe(), self.get_info()
        return observation, reward, terminated, truncated, info

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
