"""A tiny pure-numpy image env for tests and demos: move a red dot onto a green target.

`import learner.testing_envs` registers "DotReach-v0"; make it as "learner.testing_envs:DotReach-v0".
The observation is an RGB image (obs_size px; 24 by default); render() draws the same state at render_size.
info["success"] is True when the dot is within `radius` of the target (unless report_success=False);
info["hand_distance"] is the dot's distance to the target (the dot is the hand).
"""

import importlib
from typing import Any

import gymnasium as gym
import numpy as np

TARGET = np.array([0.5, 0.5], dtype=np.float32)


class DotReach(gym.Env[np.ndarray, np.ndarray]):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self, obs_size: int = 24, render_size: int = 64, render_mode: str | None = None, radius: float = 0.3,
        report_success: bool = True, target: tuple[float, float] = (0.5, 0.5), start: tuple[float, float] = (-0.9, 0.1),
    ) -> None:  # fmt: skip
        """`target`: the green disc's centre; `start`: the range of each coordinate of the dot's start."""
        self.obs_size, self.render_size, self.render_mode = obs_size, render_size, render_mode
        self.radius, self.report_success = radius, report_success
        self.target, self.start = np.asarray(target, dtype=np.float32), start
        self.observation_space = gym.spaces.Box(0, 255, (obs_size, obs_size, 3), dtype=np.uint8)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)
        self.position = np.zeros(2, dtype=np.float32)

    def _draw(self, size: int) -> np.ndarray:
        grid = (np.arange(size, dtype=np.float32) + 0.5) / size * 2.0 - 1.0
        xs, ys = np.meshgrid(grid, grid)
        image = np.full((size, size, 3), 30, dtype=np.uint8)
        image[(xs - self.target[0]) ** 2 + (ys - self.target[1]) ** 2 < 0.25**2] = (40, 200, 60)
        image[(xs - self.position[0]) ** 2 + (ys - self.position[1]) ** 2 < 0.18**2] = (230, 40, 40)
        return image

    def _info(self) -> dict[str, Any]:
        distance = float(np.linalg.norm(self.position - self.target))
        info: dict[str, Any] = {"distance": distance, "hand_distance": distance, "position": self.position.copy()}
        if self.report_success:
            info["success"] = distance < self.radius
        return info

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.position = self.np_random.uniform(*self.start, size=2).astype(np.float32)
        return self._draw(self.obs_size), self._info()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        delta = 0.15 * np.clip(np.asarray(action, dtype=np.float32), -1.0, 1.0)
        self.position = np.clip(self.position + delta, -1.0, 1.0).astype(np.float32)
        info = self._info()
        return self._draw(self.obs_size), -info["distance"], False, False, info

    def render(self) -> np.ndarray | None:
        return self._draw(self.render_size) if self.render_mode == "rgb_array" else None

    # the optional state-snapshot protocol (contract.envs.snapshot_of): its query candidates are scored in batches
    def state_snapshot(self) -> np.ndarray:
        return self.position.copy()

    def restore_snapshot(self, snapshot: np.ndarray) -> None:
        self.position = np.asarray(snapshot, dtype=np.float32).copy()


class BadObservationDot(DotReach):
    """DotReach whose observations are not images the networks can take, from step `bad_from` on (0: at reset):
    "nan" (a float image with NaN values), "huge" (float values up to 1e9), "text" (a string), "gray" (H x W).
    Its render() is the ordinary one. Registered as VisualNaN-v0, VisualNaNLater-v0 (NaN from the third step),
    VisualHuge-v0, VisualText-v0 and VisualGray-v0."""

    def __init__(self, bad: str = "nan", bad_from: int = 0, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.bad, self.bad_from, self.steps = bad, bad_from, 0

    def _observation(self) -> Any:
        image = self._draw(self.obs_size)
        if self.steps < self.bad_from:
            return image
        if self.bad == "nan":
            spoilt = image.astype(np.float32) / 255.0
            spoilt[0, 0] = np.nan
            return spoilt
        if self.bad == "huge":
            spoilt = image.astype(np.float32) * (1e9 / 255.0)
            spoilt[0, 0], spoilt[-1, -1] = 0.0, 1e9
            return spoilt
        if self.bad == "text":
            return "a picture of a dot"
        if self.bad == "gray":
            return image[..., 0]
        raise ValueError(f"unknown kind of bad observation {self.bad!r}")

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        _image, info = super().reset(seed=seed, options=options)
        self.steps = 0
        return self._observation(), info

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        _image, reward, terminated, truncated, info = super().step(action)
        self.steps += 1
        return self._observation(), reward, terminated, truncated, info


class MissingDependencyDot(DotReach):
    """DotReach that needs a module which is not installed, as Gymnasium's Pusher-v5 needs imageio: making it fails
    with "No module named 'a_module_that_is_not_installed'". Registered as VisualNeedsMissingModule-v0."""

    def __init__(self, **kwargs: Any) -> None:
        importlib.import_module("a_module_that_is_not_installed")
        super().__init__(**kwargs)


BAD_OBSERVATION_ENVS = {
    "VisualNaN-v0": {"bad": "nan"},
    "VisualNaNLater-v0": {"bad": "nan", "bad_from": 3},
    "VisualHuge-v0": {"bad": "huge"},
    "VisualText-v0": {"bad": "text"},
    "VisualGray-v0": {"bad": "gray"},
}


def add_dot_goals(store: Any, name: str = "dot") -> int:
    """A goal set of 4 DotReach goal images (16 px; display 32 px) in `store` (an contract.store.Store); its id."""
    from contract.envs import encode_png

    goal_set = store.create_goal_set(name=name, image_size=16)
    env = DotReach(obs_size=16, render_size=32)
    for i in range(4):
        env.position = TARGET + np.float32(0.05 * (i - 1.5))
        png = encode_png(env._draw(16))
        store.add_goal_example(
            goal_set_id=goal_set.id, filename=f"goal{i}.png", original=png, original_media_type="image/png",
            width=16, height=16, model_png=png, display_png=encode_png(env._draw(32)),
        )  # fmt: skip
    return goal_set.id


if "DotReach-v0" not in gym.registry:
    gym.register(id="DotReach-v0", entry_point="learner.testing_envs:DotReach", max_episode_steps=50)
if "DotReachRight-v0" not in gym.registry:  # a task SAC learns within a test's minute: the dot pushed right
    gym.register(
        id="DotReachRight-v0", entry_point="learner.testing_envs:DotReach", max_episode_steps=25,
        kwargs={"target": (1.0, 0.0), "radius": 0.7, "start": (-0.3, 0.3)},
    )  # fmt: skip
if "VisualNeedsMissingModule-v0" not in gym.registry:
    gym.register(
        id="VisualNeedsMissingModule-v0", entry_point="learner.testing_envs:MissingDependencyDot", max_episode_steps=50
    )
for _env_id, _kwargs in BAD_OBSERVATION_ENVS.items():
    if _env_id not in gym.registry:
        gym.register(
            id=_env_id, entry_point="learner.testing_envs:BadObservationDot", max_episode_steps=50, kwargs=_kwargs
        )
