"""The contract between vice-raq and a robot: a Gymnasium env whose observation is the robot's camera.

Subclass `RobotEnv` and write five methods: `read_camera`, `send_action`, `reset_scene`, `hold_safe` and,
if the robot can tell, `read_success`. Only `send_action`, `reset_scene` and `hold_safe` move or hold the arm:
`__init__` connects to the camera and the arm and never moves it, and `read_camera` only reads. One process drives
the robot: its own (`raq robot ENV_ID`, robot/drive/process.py), which reads the camera for the pages between
runs and drives the run whose learner links to it.

Armed, or it does not move: `reset()` and `step()` refuse (RobotNotArmed) unless the robot's driver armed the env
(`arm`) within the last moments, after it found in the store that it holds the robot for its run's current claim
and that no Stop is pending. An env made anywhere else (a preview, a lockstep runner, a script) raises instead of
moving, and its `close()` touches nothing. `is_robot` is the one answer to "is this a robot?", for a class, a made
env (through any wrappers) or an env id.

The base class does the rest the same way for every robot: actions are clipped to [-1, 1] and passed through your
`limit_action` (workspace bounds, speed limits; told the seconds since the previous action) before they reach the
arm; the camera's frame is centre-cropped to a square and resized exactly as goal photos are
(`contract.images.model_view`), so goals and observations look alike; `stop()` holds the arm safe and refuses
further actions until the next `reset()`.
"""

import inspect
import time
from collections.abc import Callable
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from PIL import Image

from contract.envs import env_class
from contract.images import model_view


class RobotStopped(RuntimeError):
    """An action was sent after `stop()` and before the next `reset()`."""


class RobotNotArmed(RuntimeError):
    """A move was asked of a robot that its driver has not armed (or whose arming ran out): only the robot's own
    process moves it, after taking its hold, with no Stop pending."""


class CameraBusy(OSError):
    """The camera is open in another process (most USB cameras open in one process at a time). Raise it from
    `__init__` when the camera cannot be opened for that reason: a run's actor then tries again for a while
    (robot/drive/actor.py CAMERA_BUSY_SECONDS)."""


class RobotEnv(gym.Env[np.ndarray, np.ndarray]):
    """A real robot seen through one RGB camera.

    ## Action space
    `Box(-1, 1, (action_dim,), float32)`: what each dimension means is the subclass's (e.g. end-effector
    displacements per control period). Values are clipped to [-1, 1], NaN becomes 0, and `limit_action` applies
    the robot's own safety limits before `send_action` is called. The actor sends no two actions closer than 0.9
    of a control period (a late one is sent late, never followed by an early one); `limit_action` is told the real
    time since the previous action, so a speed limit holds whatever the interval.

    ## Observation space
    `Box(0, 255, (image_size, image_size, 3), uint8)`: the camera's frame (any size), centre-cropped to a square
    and resized with the same filter as the goal photos.

    ## Rewards
    Always 0: the reward is the learned classifier's.

    ## Starting state
    `reset()` calls `reset_scene()`: the arm goes to its start pose. With `needs_person_reset` True, a person
    then puts the scene back (the queue page's "Reset the scene, then press Ready"), and the episode starts from
    `look()`, the scene as they left it.

    ## Episode end
    By the time limit given at registration (`max_episode_steps`); `terminated` is always False.
    `info["success"]` is present when `read_success()` returns True or False.

    ## Arguments
    `image_size`: side of the observation in pixels (84 on a robot). `action_dim`: the action's size.
    `display_size`: side of the view stored for a person (queries, rollouts).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 5}
    needs_person_reset: ClassVar[bool] = True
    """A person must put the scene back before each episode."""
    control_hz: ClassVar[float] = 5.0
    """Steps per second the robot is driven at (the actor keeps this rate; the learner never makes it wait)."""

    def __init__(self, *, action_dim: int, image_size: int = 84, display_size: int = 256) -> None:
        if action_dim < 1 or image_size < 8 or display_size < 8:
            raise ValueError("action_dim must be at least 1, image_size and display_size at least 8")
        self.image_size, self.display_size = int(image_size), int(display_size)
        self.action_space = spaces.Box(-1.0, 1.0, (action_dim,), np.float32)
        self.observation_space = spaces.Box(0, 255, (self.image_size, self.image_size, 3), np.uint8)
        self.render_mode = "rgb_array"
        self.stopped = True
        """No move since the arm was last held (or let go): `close()` and `stop()` touch nothing then."""
        self.armed_until = -np.inf
        """Until when (time.monotonic()) the driver allows a move; see `arm`."""
        self.last_frame: np.ndarray | None = None
        self.last_action_at: float | None = None
        """When the last action was sent (time.monotonic()); None: none since the last reset()."""

    # ------------------------------------------------------------------ to write for your robot
    def read_camera(self) -> np.ndarray:
        """The camera's current frame: (height, width, 3) uint8 RGB, any size."""
        raise NotImplementedError

    def send_action(self, action: np.ndarray) -> None:
        """Move the arm by `action` (already clipped to [-1, 1] and within `limit_action`'s limits)."""
        raise NotImplementedError

    def reset_scene(self) -> None:
        """Bring the arm to its start pose (the objects are the person's when `needs_person_reset`)."""
        raise NotImplementedError

    def hold_safe(self) -> None:
        """Stop the arm where it is and hold it safe (brakes, zero velocity, gripper as it is)."""
        raise NotImplementedError

    def read_success(self) -> bool | None:
        """Whether the task is done now, if the robot can tell (a sensor, a marker); None: it cannot."""
        return None

    def limit_action(self, action: np.ndarray, *, seconds: float | None = None) -> np.ndarray:
        """The robot's safety limits on an action in [-1, 1] (workspace box, speed); default: none beyond it.

        `seconds`: the time since the previous action was sent (one control period for the first after a reset),
        to scale a speed limit with: a step may move the arm at most top speed × `seconds`. An override that does
        not take `seconds` (`limit_action(self, action)`) is called without it."""
        return action

    # ------------------------------------------------------------------ the same for every robot
    def set_view(self, *, image_size: int, display_size: int) -> None:
        """The observation's side and the stored view's, for the run being served (the robot's process keeps one
        env, and so its camera, for runs of any sizes). Moves nothing."""
        if image_size < 8 or display_size < 8:
            raise ValueError("image_size and display_size must be at least 8")
        self.image_size, self.display_size = int(image_size), int(display_size)
        self.observation_space = spaces.Box(0, 255, (self.image_size, self.image_size, 3), np.uint8)

    def observe(self, frame: np.ndarray) -> np.ndarray:
        """A camera frame as the networks see it: centre square, image_size pixels, as goal photos are made."""
        frame = np.asarray(frame)
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(f"the camera gave a {frame.dtype} frame of shape {frame.shape}; expected (H, W, 3) uint8")
        return np.asarray(model_view(Image.fromarray(frame), self.image_size))

    def arm(self, *, seconds: float) -> None:
        """Allow moves for the next `seconds`: called by the robot's driver only, right after the store said that it
        holds the robot for its run's current claim and that no Stop is pending."""
        self.armed_until = time.monotonic() + seconds

    def disarm(self) -> None:
        """Refuse every move from now until the driver arms the env again (a Stop, a lost hold, a silent store)."""
        self.armed_until = -np.inf

    @property
    def armed(self) -> bool:
        return time.monotonic() < self.armed_until

    def _check_armed(self, move: str) -> None:
        if not self.armed:
            raise RobotNotArmed(
                f"{type(self).__name__}.{move}: the robot is not armed; only its own process (`raq robot ENV_ID`) "
                "moves it, while it holds it and no Stop is pending"
            )

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        self._check_armed("reset")
        super().reset(seed=seed)
        self.stopped = False  # (from here on the arm may be moving: stop() holds it)
        self.reset_scene()
        self.stopped, self.last_action_at = False, None
        return self.look()

    def look(self) -> tuple[np.ndarray, dict[str, Any]]:
        """The observation and info of the scene as the camera sees it now, without moving the arm (an episode's
        first, once a person has reset the scene after `reset()`)."""
        return self._observation(), self._info()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self.stopped:
            raise RobotStopped("the robot was stopped: reset() before the next action")
        self._check_armed("step")
        action = np.nan_to_num(np.asarray(action, dtype=np.float32).reshape(self.action_space.shape), nan=0.0)
        now = time.monotonic()
        seconds = 1.0 / self.control_hz if self.last_action_at is None else now - self.last_action_at
        action = np.clip(action, -1.0, 1.0)
        if _takes_seconds(self.limit_action):
            limited = self.limit_action(action, seconds=seconds)
        else:  # (an override written without `seconds`)
            limited = self.limit_action(action)
        self.last_action_at = now
        self.send_action(np.asarray(limited, dtype=np.float32))
        return self._observation(), 0.0, False, False, self._info()

    def stop(self) -> None:
        """Hold the arm safe now, if it moved since it was last held or let go; moves are refused until the driver
        arms the env again and resets it. Only the driver calls it, and only while it holds the robot."""
        self.disarm()
        if not self.stopped:
            self.stopped = True
            self.hold_safe()

    def let_go(self) -> None:
        """Refuse further moves without touching the arm, close() included: another process may drive it now."""
        self.disarm()
        self.stopped = True

    def render(self) -> np.ndarray | None:
        """The last camera frame, aspect kept, for a person (queries, rollouts, the live view)."""
        frame = self.last_frame if self.last_frame is not None else self.read_camera()
        image = Image.fromarray(frame)
        image.thumbnail((self.display_size, self.display_size), Image.Resampling.LANCZOS)
        return np.asarray(image)

    def render_display(self) -> np.ndarray:
        """The view stored with each query for a person: the camera's square, display_size pixels."""
        frame = self.last_frame if self.last_frame is not None else self.read_camera()
        return np.asarray(model_view(Image.fromarray(frame), self.display_size))

    def close(self) -> None:
        self.stop()
        super().close()

    def _observation(self) -> np.ndarray:
        self.last_frame = np.asarray(self.read_camera())
        return self.observe(self.last_frame)

    def _info(self) -> dict[str, Any]:
        success = self.read_success()
        return {} if success is None else {"success": float(success)}


def is_robot(thing: object) -> bool:
    """Whether `thing` is a robot: a RobotEnv subclass, or a made env that is one under its wrappers. The one check
    the server, the runners and the driver ask (`robot_class` answers it for an env id)."""
    if isinstance(thing, gym.Env):
        thing = type(thing.unwrapped)
    return isinstance(thing, type) and issubclass(thing, RobotEnv)


def robot_class(env_id: str) -> bool | None:
    """Whether an env id makes a robot, from its registration, without making it: None when the registration
    cannot tell (an entry point that is a factory function); ask `is_robot` of the made env then."""
    cls = env_class(env_id)
    return None if cls is None else is_robot(cls)


def control_rate(env_id: str, control_hz: float = 0.0, env: gym.Env | None = None) -> float:
    """Steps per second of a real-time actor for this env: `control_hz` when set, else a robot's own rate (of
    `env` when made, else of its registered class); 0: in lockstep (an env that is no robot, or one whose
    registration cannot tell)."""
    if control_hz > 0:
        return float(control_hz)
    if env is not None:
        return float(env.unwrapped.control_hz) if is_robot(env) else 0.0  # type: ignore[attr-defined]
    cls = env_class(env_id)
    return float(cls.control_hz) if cls is not None and is_robot(cls) else 0.0  # type: ignore[union-attr]


def _takes_seconds(limit_action: Callable[..., Any]) -> bool:
    """Whether a `limit_action` takes the `seconds` keyword (one written before it was passed does not)."""
    function = getattr(limit_action, "__func__", limit_action)
    taken = _TAKES_SECONDS.get(function)
    if taken is None:
        parameters = inspect.signature(limit_action).parameters.values()
        taken = any(
            parameter.name == "seconds" and parameter.kind != parameter.POSITIONAL_ONLY
            or parameter.kind == parameter.VAR_KEYWORD
            for parameter in parameters
        )  # fmt: skip
        _TAKES_SECONDS[function] = taken
    return taken


_TAKES_SECONDS: dict[Any, bool] = {}
"""`_takes_seconds`' answer by function."""
