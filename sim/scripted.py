"""Scripted controllers that solve each simulated task from its ground-truth state (not from pixels).

They are used to make goal examples (door, picker), to check that every task is solvable within an episode, and
as a yardstick: `success_rate(task, "scripted")` should be high and `success_rate(task, "random")` low.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import gymnasium
import numpy as np

from sim import TASKS
from sim.base import SawyerMocapEnv
from sim.bookshelf import VisualBookshelfEnv
from sim.door import VisualDoorEnv
from sim.draping import VisualDrapingEnv
from sim.picker import VisualPickerEnv
from sim.pusher import VisualPusherEnv


def _toward(target: np.ndarray, current: np.ndarray, step: float) -> np.ndarray:
    """Action (in units of `step` metres) that moves `current` to `target`, clipped to [-1, 1]."""
    return np.clip((np.asarray(target) - np.asarray(current)) / step, -1.0, 1.0)


def pusher_action(env: VisualPusherEnv) -> np.ndarray:
    """Get behind the mug on the line through the coaster, then push it along that line, slowing near the goal."""
    mug, goal, hand = env.mug_pos, env.goal_pos, env.hand_pos[:2]
    to_goal = goal - mug
    distance = float(np.linalg.norm(to_goal))
    if distance < 0.008:
        return np.zeros(2)
    push_dir = to_goal / distance
    contact = env.mug_radius + env.pusher_radius
    offset = hand - mug
    along = float(offset @ push_dir)
    across = offset - along * push_dir
    across_dist = float(np.linalg.norm(across))
    step = env.action_scale
    if along < -0.7 * contact and across_dist < 0.012:
        # Aligned behind the mug: push towards the coaster, correcting sideways drift.
        speed = min(1.0, distance / (2.0 * step))
        return np.clip(push_dir * speed - across / step, -1.0, 1.0)
    behind = mug - push_dir * (contact + 0.012)
    radius = max(float(np.linalg.norm(offset)), 1e-6)
    radial = offset / radius
    # Signed angle from the hand's bearing (seen from the mug) to the bearing of the pushing spot behind the mug.
    angle = float(np.arctan2(radial[0] * -push_dir[1] - radial[1] * -push_dir[0], radial @ -push_dir))
    if abs(angle) > 0.5:
        # Circle round the mug, keeping clear of it, towards the pushing spot.
        turn = float(np.clip(angle, -0.6, 0.6))
        c, s = np.cos(turn), np.sin(turn)
        bearing = np.array([c * radial[0] - s * radial[1], s * radial[0] + c * radial[1]])
        return _toward(mug + bearing * (contact + 0.025), hand, step)
    return _toward(behind, hand, step)


def door_action(env: VisualDoorEnv) -> np.ndarray:
    """Reach over the handle, lower the hook's tip into the slot behind the bar, then pull straight back to 45 degrees.

    The pull is along -y at a fixed x, as the original's scripted goals did: the long bar keeps the tip in the slot
    while the door swings. The hand keeps its x where a straight pull reaches 45 degrees before the tip runs off the
    bar's free end, else it moves there first.
    """
    hand, angle, step = env.hand_pos, env.door_angle, env.action_scale
    x = float(np.clip(hand[0], *DOOR_PULL_X))
    if env.is_hooked():
        # Slow down near the goal (the angle moves about 0.1 rad per 2 cm pulled); hold x against the bar's push.
        pull = float(np.clip(5.0 * (env.target_angle - angle), -1.0, 1.0))
        return np.array([np.clip((x - hand[0]) / step, -1.0, 1.0), -pull, 0.0])
    along = env.slot_along(np.array([x, 0.0, 0.0]), angle)[0]
    slot = env.slot_point(angle, along)
    clear = slot[2] + 0.05  # the tip passes over the bar this high
    if np.linalg.norm(hand[:2] - slot[:2]) > 0.006:
        # Over the slot first (rising first when low, so the hook does not knock the bar or the door).
        if hand[2] < clear - 0.01:
            return _toward(np.array([hand[0], hand[1], clear]), hand, step)
        return _toward(np.array([slot[0], slot[1], clear]), hand, step)
    return _toward(np.array([slot[0], slot[1], slot[2] - 0.035]), hand, step)


# Hand x (m) from which a straight pull opens the door to 45 degrees with the tip still behind the bar.
DOOR_PULL_X = (-0.06, 0.0)


def picker_action(env: VisualPickerEnv) -> np.ndarray:
    """Hover over the ball with the gripper open, descend, close, then carry the ball to the goal point."""
    ball, hand, goal = env.ball_pos, env.hand_pos, env.goal_pos
    step = env.action_scale
    offset = ball - hand
    grasp_width = 2.0 * env.ball_radius + 0.01
    near_xy = float(np.linalg.norm(offset[:2]))
    if near_xy < 0.02 and abs(offset[2]) < 0.02 and env.gripper_opening < grasp_width:
        return np.append(_toward(goal, ball, step), 1.0)
    hover = np.array([ball[0], ball[1], ball[2] + 0.08])
    if near_xy > 0.01:
        if hand[2] < ball[2] + 0.06:
            return np.append(_toward(np.append(hand[:2], hover[2]), hand, step), -1.0)
        return np.append(_toward(hover, hand, step), -1.0)
    if hand[2] > ball[2] + 0.005:
        return np.append(_toward(ball, hand, step), -1.0)
    return np.array([0.0, 0.0, 0.0, 1.0])


def bookshelf_action(env: VisualBookshelfEnv) -> np.ndarray:
    """Over the nearer empty slot at the start height, then straight down into it."""
    hand, step = env.hand_pos, env.action_scale
    slot = env.slot_x[int(np.argmin(np.abs(env.slot_x - hand[0])))]
    if abs(slot - hand[0]) < 0.004:
        return np.array([np.clip((slot - hand[0]) / step, -1.0, 1.0), -1.0])
    height = np.clip((env.hand_init[2] - hand[2]) / step, -1.0, 1.0)  # (up first: a standing book is in the way)
    return np.array([np.clip((slot - hand[0]) / step, -1.0, 1.0), height])


DRAPE_WAYPOINTS = ((-0.08, 0.36), (0.0, 0.24), (0.06, 0.14), VisualDrapingEnv.hand_goal)
"""The draping hand's path (y, z): up and over the near edge, the cloth laid across the top, down the far side."""


def draping_action(env: VisualDrapingEnv) -> np.ndarray:
    """Toward the first waypoint still ahead (along y) of the hand: the cloth is laid over the box, not dragged."""
    hand, step = env.hand_pos[1:], env.action_scale
    ahead = [point for point in DRAPE_WAYPOINTS if point[0] > hand[0] + 0.005]
    target = np.array(ahead[0] if ahead else DRAPE_WAYPOINTS[-1])
    return np.clip((target - hand) / step, -1.0, 1.0)


_CONTROLLERS: dict[type[SawyerMocapEnv], Callable[..., np.ndarray]] = {
    VisualPusherEnv: pusher_action,
    VisualDoorEnv: door_action,
    VisualPickerEnv: picker_action,
    VisualBookshelfEnv: bookshelf_action,
    VisualDrapingEnv: draping_action,
}


def scripted_action(env: gymnasium.Env) -> np.ndarray:
    """The scripted controller's action for the current state of `env` (a made env or its unwrapped task env)."""
    task_env = env.unwrapped
    for env_class, controller in _CONTROLLERS.items():
        if isinstance(task_env, env_class):
            return controller(task_env).astype(np.float32)
    raise TypeError(f"no scripted controller for {type(task_env).__name__}")


def success_rate(
    task: str, policy: Literal["scripted", "random"] = "scripted", episodes: int = 20, seed: int = 0
) -> float:
    """Fraction of `episodes` 100-step episodes (reset seeds seed, seed+1, ...) that end in success."""
    if policy not in ("scripted", "random"):
        raise ValueError(f"policy must be 'scripted' or 'random', not {policy!r}")
    env = gymnasium.make(TASKS[task])
    env.action_space.seed(seed)
    successes = 0.0
    try:
        for episode in range(episodes):
            env.reset(seed=seed + episode)
            info: dict = {}
            truncated = terminated = False
            while not (truncated or terminated):
                action = scripted_action(env) if policy == "scripted" else env.action_space.sample()
                _, _, terminated, truncated, info = env.step(action)
            successes += info["success"]
    finally:
        env.close()
    return successes / episodes
