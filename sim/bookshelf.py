"""Visual Bookshelf: put a held book into any empty slot of a row of standing books, seen from the front."""

from __future__ import annotations

from typing import Any, ClassVar

import mujoco
import numpy as np

from sim.base import SawyerMocapEnv


class VisualBookshelfEnv(SawyerMocapEnv):
    """
    ## Description
    A Sawyer-like end effector holds a red book by its top above a shelf of standing books. Two of the row's nine
    places are empty (x = -8 cm and x = +8 cm): the goal is to lower the book into either one. A goal classifier
    is not a goal image: either slot is a success, and the nearer one is the quicker. This is the *Visual
    Bookshelf* task of "End-to-End Robotic Reinforcement Learning without Reward Engineering" (Singh et al., 2019),
    in simulation; the policy sees only the camera image.

    ## Action Space
    `Box(-1, 1, (2,), float32)`: the desired displacement (dx, dz) of the end effector along the shelf and up or
    down, 2 cm per unit, applied to a mocap target that the hand follows; the target is clipped to x in
    [-0.17, 0.17], z in [0.15, 0.4] (metres). The held book is part of the hand: a standing book stops it.

    | Num | Action                           | Min | Max | Unit          |
    |-----|----------------------------------|-----|-----|---------------|
    | 0   | displacement of the hand along x | -1  | 1   | 2 cm per unit |
    | 1   | displacement of the hand along z | -1  | 1   | 2 cm per unit |

    ## Observation Space
    `Box(0, 255, (image_size, image_size, 3), uint8)`: an RGB image from the fixed camera `task_camera` in front of
    the shelf, looking at it 15 degrees downward.

    ## Rewards / success
    `info["success"]` is 1.0 when the held book's bottom is below `inserted_height` (4 cm: most of it among the
    standing books, 14.4-16 cm tall) within `slot_tolerance` (1.5 cm) of an empty slot's centre along the shelf, else
    0.0; the standing books
    leave no other way down. The reward of `step` is that flag. `info` also holds `book_bottom` (m), `slot` (the
    index of the slot the book is nearest, 0 or 1), `slot_offset` (m, along x) and `hand_pos` (x, y, z).

    ## Starting State
    The hand starts at rest at height 36 cm (the 15 cm book's bottom 5 cm above the tallest standing book), at x ~
    U[-0.15, 0.15] along the shelf, drawn from `self.np_random`.

    ## Episode End
    There is no terminal state: the episode is truncated after 100 steps by the registered `max_episode_steps`.

    ## Arguments
    `gymnasium.make("VisualBookshelf-v0", image_size=48, render_mode=None, render_size=256)`, as the other tasks.
    """

    xml_file: ClassVar[str] = "bookshelf.xml"
    action_dim: ClassVar[int] = 2
    shelf_y: ClassVar[float] = 0.1
    hand_low: ClassVar[tuple[float, float, float]] = (-0.17, shelf_y, 0.15)
    hand_high: ClassVar[tuple[float, float, float]] = (0.17, shelf_y, 0.4)
    hand_init: ClassVar[tuple[float, float, float]] = (0.0, shelf_y, 0.36)
    start_x: ClassVar[tuple[float, float]] = (-0.15, 0.15)
    book_height: ClassVar[float] = 0.15
    """From the hand (the book's top) to the held book's bottom."""
    inserted_height: ClassVar[float] = 0.04
    slot_tolerance: ClassVar[float] = 0.015

    def __init__(self, image_size: int = 48, render_mode: str | None = None, render_size: int = 256) -> None:
        super().__init__(image_size=image_size, render_mode=render_mode, render_size=render_size)
        mujoco.mj_forward(self.model, self.data)
        slots = [self.data.site_xpos[self.model.site(f"slot_{index}").id, 0] for index in range(2)]
        self._slot_x = np.array(slots)
        self._slot_x.flags.writeable = False

    @property
    def slot_x(self) -> np.ndarray:
        """The empty slots' centres along the shelf (x): fixed for the life of the env."""
        return self._slot_x.copy()

    @property
    def book_bottom(self) -> float:
        """Height of the held book's bottom above the shelf's floor."""
        return float(self.hand_pos[2] - self.book_height)

    def _reset_task(self) -> None:
        x = float(self.np_random.uniform(*self.start_x))
        self.set_hand_pos(np.array([x, self.shelf_y, self.hand_init[2]]))

    def _apply_action(self, action: np.ndarray) -> None:
        self._move_hand(np.array([action[0], 0.0, action[1]]))

    def get_info(self) -> dict[str, Any]:
        hand = self.hand_pos
        offsets = hand[0] - self._slot_x
        slot = int(np.argmin(np.abs(offsets)))
        bottom = float(hand[2] - self.book_height)
        inserted = bottom <= self.inserted_height and abs(offsets[slot]) <= self.slot_tolerance
        return {
            "success": float(inserted), "book_bottom": bottom, "slot": slot, "slot_offset": float(offsets[slot]),
            "hand_pos": hand,
        }  # fmt: skip
