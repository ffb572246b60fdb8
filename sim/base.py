"""Shared machinery of the simulated tasks: a Sawyer-like end effector driven through a mocap body, seen by a camera.

Every task env loads one MJCF file from `sim/assets`, moves the hand by end-effector position control (the action
is a displacement of the mocap target, 2 cm per unit, clipped to a workspace box; a soft `connect` equality pulls
the hand body after it) and observes the scene as an RGB image from the model's camera named `task_camera`.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

from pathlib import Path
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

ASSETS_DIR = Path(__file__).resolve().parent / "assets"

TIMESTEP_S = 0.005
FRAME_SKIP = 10
SNAPSHOT_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION


def _contiguous(indices: list[int]) -> slice | np.ndarray:
    """A slice when the indices are consecutive (cheaper to index with), else an index array."""
    start = int(indices[0])
    if list(indices) == list(range(start, start + len(indices))):
        return slice(start, start + len(indices))
    return np.array(indices)


class SawyerMocapEnv(gym.Env[np.ndarray, np.ndarray]):
    """Base class: pixels in, end-effector displacements out. Subclasses define the task.

    Subclasses set `xml_file`, `action_dim`, the workspace (`hand_low`, `hand_high`), `hand_init`, and implement
    `_reset_task`, `_apply_action` (usually through `_move_hand`) and `get_info`.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": ["rgb_array"],
        "render_fps": round(1.0 / (TIMESTEP_S * FRAME_SKIP)),
    }

    xml_file: ClassVar[str]
    action_dim: ClassVar[int]
    hand_low: ClassVar[tuple[float, float, float]]
    hand_high: ClassVar[tuple[float, float, float]]
    hand_init: ClassVar[tuple[float, float, float]]
    camera_name: ClassVar[str] = "task_camera"
    # Physics steps of TIMESTEP_S per env step: the time an action has to take effect.
    frame_skip: ClassVar[int] = FRAME_SKIP
    action_scale: ClassVar[float] = 0.02
    # How far the mocap target may lead the hand: bounds the pull when the hand is blocked by an object.
    max_target_lead: ClassVar[float] = 0.04

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls.metadata = {**cls.metadata, "render_fps": round(1.0 / (TIMESTEP_S * cls.frame_skip))}

    def __init__(self, image_size: int = 48, render_mode: str | None = None, render_size: int = 256) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, not {render_mode!r}")
        if image_size < 8 or render_size < 8:
            raise ValueError(f"image_size and render_size must be at least 8, got {image_size} and {render_size}")
        self.image_size = int(image_size)
        self.render_size = int(render_size)
        self.render_mode = render_mode

        self.model = mujoco.MjModel.from_xml_path(str(ASSETS_DIR / self.xml_file))
        self.model.opt.timestep = TIMESTEP_S
        self.data = mujoco.MjData(self.model)
        self._renderers: dict[int, mujoco.Renderer] = {}

        self._hand_body = self.model.body("hand").id
        self._mocap = int(self.model.body_mocapid[self.model.body("hand_mocap").id])
        self._hand_qpos = _contiguous([self.model.joint(f"hand_{axis}").qposadr[0] for axis in "xyz"])
        self._hand_qvel = _contiguous([self.model.joint(f"hand_{axis}").dofadr[0] for axis in "xyz"])
        self._hand_low = np.array(self.hand_low, dtype=np.float64)
        self._hand_high = np.array(self.hand_high, dtype=np.float64)

        self.observation_space = spaces.Box(0, 255, (self.image_size, self.image_size, 3), np.uint8)
        self.action_space = spaces.Box(-1.0, 1.0, (self.action_dim,), np.float32)

    # ------------------------------------------------------------------ gymnasium API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        self.set_hand_pos(np.array(self.hand_init, dtype=np.float64))
        self._reset_task()
        mujoco.mj_forward(self.model, self.data)
        return self._observe(), self.get_info()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        action = np.asarray(action, dtype=np.float64)
        if action.shape != self.action_space.shape:
            action = action.reshape(self.action_space.shape)
        self._apply_action(np.minimum(np.maximum(action, -1.0), 1.0))
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
        # mj_step leaves positions computed before its last integration (5 ms stale): the image and the ground
        # truth are of the state the step ended in, exactly as a state snapshot of it renders later
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)
        if self.model.nflex:  # (a cloth's vertices, from the bodies' positions)
            mujoco.mj_flex(self.model, self.data)
        info = self.get_info()
        return self._observe(), float(info["success"]), False, False, info

    def render(self) -> np.ndarray | None:
        """The display view (`render_size` pixels square) when `render_mode="rgb_array"`, else None."""
        if self.render_mode == "rgb_array":
            return self.render_display()
        return None

    def close(self) -> None:
        for renderer in self._renderers.values():
            renderer.close()
        self._renderers.clear()

    # ------------------------------------------------------------------ images
    def render_image(self, size: int) -> np.ndarray:
        """The current state seen from `task_camera` as a fresh (size, size, 3) uint8 array."""
        renderer = self._renderers.get(size)
        if renderer is None:
            visual = self.model.vis.global_
            visual.offwidth = max(visual.offwidth, size)
            visual.offheight = max(visual.offheight, size)
            renderer = self._renderers[size] = mujoco.Renderer(self.model, size, size)
        renderer.update_scene(self.data, camera=self.camera_name)
        return renderer.render()

    def render_display(self) -> np.ndarray:
        """The larger view for a person: same camera and state as the observation, `render_size` pixels square."""
        return self.render_image(self.render_size)

    def _observe(self) -> np.ndarray:
        return self.render_image(self.image_size)

    # ------------------------------------------------------------------ state snapshots
    def state_snapshot(self) -> np.ndarray:
        """The whole simulation state (MuJoCo's mjSTATE_INTEGRATION: time, qpos, qvel, actuators, mocap targets,
        controls, warm start), enough to see or continue exactly this state later."""
        snapshot = np.empty(mujoco.mj_stateSize(self.model, SNAPSHOT_SPEC))
        mujoco.mj_getState(self.model, self.data, snapshot, SNAPSHOT_SPEC)
        return snapshot

    def restore_snapshot(self, snapshot: np.ndarray) -> None:
        """Put the simulation back into the state `snapshot` was taken of."""
        mujoco.mj_setState(self.model, self.data, snapshot, SNAPSHOT_SPEC)
        mujoco.mj_forward(self.model, self.data)

    # ------------------------------------------------------------------ hand
    @property
    def dt(self) -> float:
        """Seconds of simulated time per env step."""
        return self.model.opt.timestep * self.frame_skip

    @property
    def hand_pos(self) -> np.ndarray:
        """World position of the end effector's tool point."""
        return self.data.xpos[self._hand_body].copy()

    def set_hand_pos(self, pos: np.ndarray) -> None:
        """Teleport the hand and its mocap target to `pos` (clipped to the workspace), at rest."""
        pos = np.clip(np.asarray(pos, dtype=np.float64), self._hand_low, self._hand_high)
        self.data.qpos[self._hand_qpos] = pos
        self.data.qvel[self._hand_qvel] = 0.0
        self.data.mocap_pos[self._mocap] = pos
        mujoco.mj_forward(self.model, self.data)

    def _move_hand(self, delta: np.ndarray) -> None:
        """Move the mocap target by `delta` (in action units, 2 cm each) inside the workspace."""
        target = self.data.mocap_pos[self._mocap] + self.action_scale * delta
        np.minimum(np.maximum(target, self._hand_low, out=target), self._hand_high, out=target)
        hand = self.data.qpos[self._hand_qpos]
        lead = target - hand
        np.minimum(np.maximum(lead, -self.max_target_lead, out=lead), self.max_target_lead, out=lead)
        self.data.mocap_pos[self._mocap] = hand + lead

    # ------------------------------------------------------------------ task hooks
    def _reset_task(self) -> None:
        raise NotImplementedError

    def _apply_action(self, action: np.ndarray) -> None:
        raise NotImplementedError

    def get_info(self) -> dict[str, Any]:
        """Ground truth of the current state: `success` (0.0 or 1.0) and the quantities it is decided from."""
        raise NotImplementedError
