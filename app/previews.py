"""Env previews: an env's first frames (the observation as the model sees it and the display render), made with
gymnasium in this process (no torch), one env at a time on one thread of their own, kept in a bounded cache; and the
envs the New run form suggests.

A robot env is never made or reset here (a reset moves the arm): its preview is its camera's current frame, read
as the goal-set page's live view reads it (app/camera.py: the frames of a run's actor while one drives the robot),
and a run of it is created without reading the camera (its actor opens it)."""

import threading
from collections import OrderedDict
from concurrent.futures import Future, ThreadPoolExecutor
from functools import lru_cache

import numpy as np
from PIL import Image

from app.camera import CameraUnavailable, cameras
from contract.envs import BadObservation, encode_png, env_id_problem, first_frames, module_env_ids
from contract.images import model_view
from contract.settings import Settings
from contract.store import Store
from robot.base import RobotNotArmed, robot_class

PREVIEW_SIZES = (16, 24, 32, 40, 48, 56, 64, 72, 80, 84, 96, 112, 128, 160, 192, 224, 256)
"""The model image sizes a preview is made at: a bounded set, so that callers cannot make the server build and keep
one env per size they invent."""
PREVIEW_CACHE_ENTRIES = 24
"""First frames kept (a few KB of PNG each); the least recently used goes first."""
DISPLAY_SIZE = 256


class FirstFrames:
    """A bounded cache of first frames by (env id, size). Every env is made on one thread of its own, one at a time:
    a rendering context (EGL, OSMesa) stays with the thread that made it, so envs made on the request threads kept
    about 12 MB each of up to 40 threads. Callers who wait while frames are made get the one result: 80 callers at
    once make each env once, not 80 times."""

    def __init__(self, entries: int) -> None:
        self.entries = entries
        self._made: OrderedDict[tuple[str, int], tuple[bytes, bytes, str]] = OrderedDict()
        self._making: dict[tuple[str, int], Future[tuple[bytes, bytes, str]]] = {}
        self._lock = threading.RLock()  # (a made future's callback may run inside get, under its lock)
        self._maker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="env-preview")

    def get(self, env_id: str, size: int) -> tuple[bytes, bytes, str]:
        """The frames, from the cache or made once however many wait for them (a kept frame never waits for
        another env being made); an error is raised to every waiter and not kept."""
        key = (env_id, size)
        with self._lock:
            if key in self._made:
                self._made.move_to_end(key)
                return self._made[key]
            making = self._making.get(key)
            if making is None:
                making = self._making[key] = self._maker.submit(
                    first_frames, env_id, image_size=size, display_size=DISPLAY_SIZE
                )
                making.add_done_callback(lambda done: self._keep(key, done))
        return making.result()

    def _keep(self, key: tuple[str, int], done: "Future[tuple[bytes, bytes, str]]") -> None:
        with self._lock:
            del self._making[key]
            if done.exception() is None:
                self._made[key] = done.result()
                while len(self._made) > self.entries:
                    self._made.popitem(last=False)


_first_frames = FirstFrames(PREVIEW_CACHE_ENTRIES)


def preview_size(size: int) -> int:
    """The listed preview size nearest to a run's image size (its env is checked at that size)."""
    return min(PREVIEW_SIZES, key=lambda listed: (abs(listed - size), listed))


def preview_frames(env_id: str, size: int, settings: Settings, store: Store) -> tuple[bytes, bytes, str] | str:
    """The env's first frames and description (as the preview shows them), or why a run of it cannot start: an
    id that is not allowed or registered, an env that cannot be made or reset, or an observation that is not an
    image (contract.envs.observation_problem: "<env id>: observation has NaN values"). A robot env's are its
    camera's current frame (robot_preview)."""
    problem = env_id_problem(env_id, allowed_modules=settings.env_modules)
    if problem:
        return problem
    if is_robot(env_id):
        return robot_preview(env_id, preview_size(size), store)
    frames = _preview_of_env(env_id, size)
    return robot_preview(env_id, preview_size(size), store) if is_robot(env_id) else frames


def preview_problem(env_id: str, size: int, settings: Settings) -> str | None:
    """Why a run of the env cannot be created, or None. The New run form's preview and run creation both ask this,
    so a run is created only of an env whose preview works; a robot env is only checked to be allowed and to be a
    robot (its camera may be another process's: the run's actor opens it)."""
    problem = env_id_problem(env_id, allowed_modules=settings.env_modules)
    if problem or is_robot(env_id):
        return problem
    frames = _preview_of_env(env_id, size)
    return frames if isinstance(frames, str) and not is_robot(env_id) else None


_made_robots: set[str] = set()
"""Env ids whose registration could not tell (a factory function) and whose env, once made, was a robot."""


def is_robot(env_id: str) -> bool:
    """An allowed env id of a robot (robot.base.robot_class): never made for a preview when its registration says
    so; one registered by a factory function is made once, and its guard refuses the preview's reset."""
    try:
        return bool(robot_class(env_id)) or env_id in _made_robots
    except Exception:  # noqa: BLE001 - a class that cannot be read is answered by making the env (its error)
        return False


def robot_preview(env_id: str, size: int, store: Store) -> tuple[bytes, bytes, str]:
    """A robot's camera frame, as its process published it, as the model sees it and as a person does; grey frames
    and the reason when there is none (no robot process up: the env is a robot's all the same)."""
    try:
        frame = cameras.frame(env_id, store)
    except CameraUnavailable as error:  # a robot env all the same: grey frames, and why there is no picture
        blank = np.full((size, size, 3), 128, np.uint8)
        return (
            encode_png(blank),
            encode_png(np.full((3 * DISPLAY_SIZE // 4, DISPLAY_SIZE, 3), 128, np.uint8)),
            (f"a robot's camera, no frame to show: {error}"[:500]),
        )
    image = Image.fromarray(frame.pixels)
    display = image.copy()
    display.thumbnail((DISPLAY_SIZE, DISPLAY_SIZE), Image.Resampling.LANCZOS)
    description = f"a robot's camera ({frame.width}x{frame.height}, {frame.source}): the preview is its current frame"
    return encode_png(np.asarray(model_view(image, size))), encode_png(np.asarray(display)), description


def _preview_of_env(env_id: str, size: int) -> tuple[bytes, bytes, str] | str:
    """An env's first frames after reset (made once a size, kept), or why it cannot be made or reset."""
    try:
        return _first_frames.get(env_id, preview_size(size))
    except RobotNotArmed as error:  # (a robot after all: its arm refused to move, and it is never made again)
        _made_robots.add(env_id)
        return str(error)
    except BadObservation as error:
        return str(error)[:500]
    except Exception as error:  # noqa: BLE001 - any failure of the env itself is the user's answer, not a 500
        return f"cannot make or reset {env_id!r}: {type(error).__name__}: {error}".splitlines()[0][:500]


@lru_cache(maxsize=8)
def _suggested(modules: tuple[str, ...]) -> tuple[str, ...]:
    settings = Settings(_env_file=None, env_modules=modules)  # type: ignore[call-arg]
    found: list[str] = []
    for module in modules:
        try:
            candidates = module_env_ids(module)
        except Exception:  # noqa: BLE001 - a module that cannot be imported suggests nothing (its ids say why)
            continue
        found += [env_id for env_id in candidates if preview_problem(env_id, 48, settings) is None]
    return tuple(found)


def suggested_env_ids(settings: Settings) -> list[str]:
    """What the New run form suggests besides the simulated tasks: every env the allowed modules register whose
    preview works (an image observation), as module:EnvId, the one id a learner can make. Found once a process."""
    return list(_suggested(tuple(settings.env_modules)))
