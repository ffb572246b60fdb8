"""Visual Draping: drape a cloth, held by one edge, over a box without folding it onto itself."""

from __future__ import annotations

from typing import Any, ClassVar

import mujoco
import numpy as np

from sim.base import SawyerMocapEnv


class VisualDrapingEnv(SawyerMocapEnv):
    """
    ## Description
    A Sawyer-like end effector holds a 15 x 25 cm cloth (a MuJoCo flex: a 7 x 11 grid of vertices) by one short
    edge in front of a 12 x 10 x 8 cm box. The goal is to drape the cloth over the box: lying flat on its top and
    hanging down its near and far sides. Dragging the cloth straight toward where the hand ends (what a reward on
    the end effector's distance to that point asks for) pulls it across the top with its free edge spread out on
    the table in front; the cloth must instead be lifted, laid over the near edge and drawn across. This is the *Visual
    Draping* task of "End-to-End Robotic Reinforcement Learning without Reward Engineering" (Singh et al., 2019),
    in simulation; the policy sees only the camera image.

    ## Action Space
    `Box(-1, 1, (2,), float32)`: the desired displacement (dy, dz) of the end effector toward the box's far side
    and up or down, 2 cm per unit, applied to a mocap target that the hand follows; the target is clipped to y in
    [-0.22, 0.16], z in [0.04, 0.4] (metres).

    | Num | Action                                   | Min | Max | Unit          |
    |-----|------------------------------------------|-----|-----|---------------|
    | 0   | displacement of the hand along y (depth) | -1  | 1   | 2 cm per unit |
    | 1   | displacement of the hand along z         | -1  | 1   | 2 cm per unit |

    ## Observation Space
    `Box(0, 255, (image_size, image_size, 3), uint8)`: an RGB image from the fixed camera `task_camera`, in front
    of the box and to its side, looking down at it.

    ## Rewards / success
    `info["success"]` is 1.0 when, from the cloth's vertices: at least `covering_vertices` (14) lie on the box's top
    (within its outline, at most 2 cm above it), the cloth's free edge hangs down the near face (on average at
    least `hang_depth`, 3 cm, below the top and within `hang_reach`, 4 cm, of the face: not spread out on the table),
    the cloth hangs at least 3 cm below the top beyond the far face, and no column of the grid runs back on itself
    by more than `fold_tolerance` (5 cm along the depth: a fold), else 0.0. The reward of `step` is that flag.
    `info` also holds `covering` (the vertices on the top), `near_hang` and `far_hang` (1.0 or 0.0), `fold` (m),
    `hand_pos` and `hand_distance`: the hand's distance (m) to `hand_goal`, where it is when the cloth is draped
    (what a hand-made reward on the end effector reads: the `hand_distance` method).

    ## Starting State
    The hand starts at rest at height 30 cm (the cloth's free edge about 5 cm above the table: below the box's top) at
    y ~ U[-0.20, -0.14] in front of the box, drawn from `self.np_random`; the cloth hangs still.

    ## Episode End
    There is no terminal state: the episode is truncated after 100 steps by the registered `max_episode_steps`.

    ## Arguments
    `gymnasium.make("VisualDraping-v0", image_size=48, render_mode=None, render_size=256)`, as the other tasks.
    """

    xml_file: ClassVar[str] = "draping.xml"
    action_dim: ClassVar[int] = 2
    hand_low: ClassVar[tuple[float, float, float]] = (0.0, -0.22, 0.04)
    hand_high: ClassVar[tuple[float, float, float]] = (0.0, 0.16, 0.4)
    hand_init: ClassVar[tuple[float, float, float]] = (0.0, -0.17, 0.3)
    start_y: ClassVar[tuple[float, float]] = (-0.2, -0.14)
    hand_goal: ClassVar[tuple[float, float]] = (0.075, 0.06)
    """Where the hand (y, z) is when the cloth is draped: beyond the box's far face, low."""
    grid: ClassVar[tuple[int, int]] = (7, 11)
    """The cloth's vertices: across its width (x), along its length (from the free edge to the held one)."""
    covering_vertices: ClassVar[int] = 14
    hang_depth: ClassVar[float] = 0.03
    hang_reach: ClassVar[float] = 0.04
    """How far in front of the near face the hanging free edge may be (further out, it lies on the table)."""
    fold_tolerance: ClassVar[float] = 0.05
    settle_seconds: ClassVar[float] = 0.5
    """Simulated time the cloth hangs at the start before the first observation."""

    def __init__(self, image_size: int = 48, render_mode: str | None = None, render_size: int = 256) -> None:
        super().__init__(image_size=image_size, render_mode=render_mode, render_size=render_size)
        box = self.model.geom("box").id
        centre, half = self.model.geom_pos[box].copy(), self.model.geom_size[box].copy()
        self._box_top = float(centre[2] + half[2])
        self._box_half = half[:2]
        self._box_centre = centre[:2]

    @property
    def box_top(self) -> float:
        """Height of the box's top above the table."""
        return self._box_top

    @property
    def cloth_vertices(self) -> np.ndarray:
        """The cloth's vertices' world positions, shaped (width, length, 3): [:, 0] the free edge, [:, -1] held."""
        return self.data.flexvert_xpos.reshape(*self.grid, 3).copy()

    def _reset_task(self) -> None:
        y = float(self.np_random.uniform(*self.start_y))
        self.set_hand_pos(np.array([0.0, y, self.hand_init[2]]))
        mujoco.mj_step(self.model, self.data, nstep=round(self.settle_seconds / self.model.opt.timestep))

    def _apply_action(self, action: np.ndarray) -> None:
        self._move_hand(np.array([0.0, action[0], action[1]]))

    def get_info(self) -> dict[str, Any]:
        vertices = self.data.flexvert_xpos.reshape(*self.grid, 3)
        across, depth, height = vertices[..., 0], vertices[..., 1], vertices[..., 2]
        inside = (np.abs(across - self._box_centre[0]) <= self._box_half[0]) & (
            np.abs(depth - self._box_centre[1]) <= self._box_half[1]
        )
        covering = int(np.count_nonzero(inside & (height <= self._box_top + 0.02)))
        low = height < self._box_top - self.hang_depth
        near_face, far_face = self._box_centre[1] - self._box_half[1], self._box_centre[1] + self._box_half[1]
        free_depth, free_height = float(np.mean(depth[:, 0])), float(np.mean(height[:, 0]))
        # the free edge hangs down the near face (not spread out on the table in front, as a dragged cloth lies)
        near = near_face - self.hang_reach <= free_depth <= near_face and free_height < self._box_top - self.hang_depth
        far = bool(np.any(low & (depth > far_face + 0.005)))
        # from the free edge to the held one a draped cloth only ever goes on toward the far side: what a column
        # runs back toward the near side is folded onto itself
        steps = np.diff(depth, axis=1)
        fold = float(np.max(np.sum(np.maximum(-steps, 0.0), axis=1)))
        success = covering >= self.covering_vertices and near and far and fold <= self.fold_tolerance
        return {
            "success": float(success), "covering": covering, "near_hang": float(near), "far_hang": float(far),
            "fold": fold, "hand_pos": self.hand_pos,
            "hand_distance": float(np.linalg.norm(self.hand_pos[1:] - np.asarray(self.hand_goal))),
        }  # fmt: skip
