"""The server's view through a robot's camera: the goal-set page's live view, its Capture, and the check of an
uploaded photo against what the camera sees.

Which envs have a camera: the allowed envs (the project's stand-in robot and RAQ_ENV_MODULES's envs, the ids a
learner can make) whose class, read from gymnasium's registry entry point without making the env, is a
`robot.base.RobotEnv` that implements `read_camera`.

One open env per env id, made on first use and shared by every request. Each is owned by its own thread: a
rendering context (MuJoCo's EGL) or a camera handle belongs to the thread that opened it, and the frames are read
with `read_camera()` alone: the server never calls `reset`, `send_action` or `hold_safe`, and lets go of the env
(`RobotEnv.let_go`) before it closes it, so that closing holds nothing either. A camera is read at most every
FRAME_INTERVAL_S (requests in between get the last frame), closed after IDLE_CLOSE_S without a request, and all
are closed by `close_cameras()` (registered with `atexit`; the app's lifespan may call it too).

A camera opens in one process at a time (most USB cameras): once a learner claims a run of the env
(Store.claimed_run_of), this server closes its env at the next request, before that run's actor opens the
camera, and serves the frames the actor publishes (Store.robot_runs) until the run ends.
"""

import atexit
import io
import queue
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import gymnasium as gym
import numpy as np
from PIL import Image

from contract.envs import SIM_ENV_IDS, encode_png, env_class, make_env, module_env_ids
from contract.images import VIEWPOINT_SIMILARITY, model_view, viewpoint_similarity
from contract.store import NotFound, Store
from robot.base import RobotEnv

PROJECT_ROBOT_MODULES = ("robot.standin",)
"""The project's own robots offered everywhere (robot.template is a file to copy, not a robot)."""
FRAME_INTERVAL_S = 0.2
"""A camera is read at most this often; requests in between get the last frame (keeps the MuJoCo stand-in cheap)."""
IDLE_CLOSE_S = 20.0
"""An env nobody asked for a frame for this long is closed, freeing the camera for a run's actor."""
READ_TIMEOUT_S = 15.0
"""The longest a request waits for the env to open and give a frame."""

ASPECT_TOLERANCE = 0.10
"""The photo's width/height may differ from the camera frame's by this fraction before it is a warning."""
SMALL_PHOTO_FRACTION = 0.5
"""A photo whose shorter side is under this fraction of the camera frame's shorter side is much smaller."""
COLOUR_MEAN_TOLERANCE = 40.0
"""A colour channel's mean (0-255, over what the model sees) may differ by this much before it is a warning."""
CONTRAST_RATIO_LIMIT = 2.0
"""The photo's brightness spread (standard deviation) may be this many times the camera's, or its inverse."""
STATS_SIDE = 64
"""Colours are compared on both images' centre squares at this side (what the model sees of each)."""
CHANNELS = ("red", "green", "blue")


class CameraUnavailable(RuntimeError):
    """The env could not be made or gave no frame, or a run's actor holds the camera and has published none."""


class CameraFrame:
    """One frame of a robot's camera: the PNG (as served and stored) and its pixels, (height, width, 3) uint8."""

    def __init__(self, *, env_id: str, png: bytes, source: str, pixels: np.ndarray | None = None) -> None:
        self.env_id, self.png, self.source = env_id, png, source
        self.taken_at = time.monotonic()
        self._pixels = pixels
        if pixels is None:
            with Image.open(io.BytesIO(png)) as header:
                self.width, self.height = header.size
        else:
            self.height, self.width = pixels.shape[:2]

    @property
    def pixels(self) -> np.ndarray:
        if self._pixels is None:
            with Image.open(io.BytesIO(self.png)) as image:
                self._pixels = np.asarray(image.convert("RGB"))
        return self._pixels


# ---------------------------------------------------------------- which envs have a camera
def has_camera(cls: type | None) -> bool:
    """A RobotEnv subclass that implements read_camera."""
    return isinstance(cls, type) and issubclass(cls, RobotEnv) and cls.read_camera is not RobotEnv.read_camera


@lru_cache(maxsize=8)
def _camera_env_ids(modules: tuple[str, ...]) -> tuple[str, ...]:
    candidates = list(SIM_ENV_IDS)
    for module in dict.fromkeys((*PROJECT_ROBOT_MODULES, *modules)):
        try:
            candidates += module_env_ids(module)
        except Exception:  # noqa: BLE001, S112 - a module that cannot be imported has no camera to offer
            continue
    found = []
    for env_id in candidates:
        try:
            if has_camera(env_class(env_id)):
                found.append(env_id)
        except Exception:  # noqa: BLE001, S112 - an entry point that does not import is no camera either
            continue
    return tuple(found)


def camera_env_ids(env_modules: Iterable[str]) -> list[str]:
    """The robot env ids with a camera, of the stand-in and the allowed modules (found once a process)."""
    return list(_camera_env_ids(tuple(env_modules)))


# ---------------------------------------------------------------- the open cameras
_CLOSE = object()


@dataclass(eq=False)
class _Camera:
    """One open env of an env id and the thread that owns it."""

    env_id: str
    jobs: "queue.Queue[Any]" = field(default_factory=queue.Queue)
    last: CameraFrame | None = None
    pending: "Future[CameraFrame] | None" = None
    thread: threading.Thread | None = None


class CameraSource:
    """The robots' cameras as this server sees them (see the module's docstring); safe to share between threads."""

    def __init__(self, make: Callable[[str], gym.Env] | None = None, *, idle_close_s: float = IDLE_CLOSE_S) -> None:
        self._make = make or (lambda env_id: make_env(env_id, image_size=84, display_size=256))
        self._idle_close_s = idle_close_s
        self._lock = threading.Lock()
        self._cameras: dict[str, _Camera] = {}
        self._actor_checked: dict[tuple[int, str], tuple[float, CameraFrame | str | None]] = {}

    def open_env_ids(self) -> list[str]:
        """The env ids whose env this server holds open now."""
        with self._lock:
            return sorted(self._cameras)

    def frame(self, env_id: str, store: Store | None = None) -> CameraFrame:
        """The camera's current frame (at most FRAME_INTERVAL_S old): a live actor's when a run's actor drives
        this env, else read here. Raises CameraUnavailable."""
        if store is not None:
            published = self._actor_frame(env_id, store)
            if published is not None:  # the actor holds the camera
                self.release(env_id)
                if isinstance(published, str):
                    raise CameraUnavailable(published)
                return published
        with self._lock:
            camera = self._cameras.get(env_id)
            if camera is None:
                camera = self._cameras[env_id] = _Camera(env_id)
                camera.thread = threading.Thread(
                    target=self._serve, args=(camera,), name=f"camera {env_id}", daemon=True
                )
                camera.thread.start()
            if camera.last is not None and time.monotonic() - camera.last.taken_at < FRAME_INTERVAL_S:
                return camera.last
            if camera.pending is None:  # concurrent requests share one read
                camera.pending = Future()
                camera.jobs.put(camera.pending)
            pending = camera.pending
        try:
            return pending.result(timeout=READ_TIMEOUT_S)
        except FutureTimeout:
            raise CameraUnavailable(f"{env_id}: the camera gave no frame in {READ_TIMEOUT_S:g} s") from None

    def release(self, env_id: str) -> None:
        """Close this server's env of env_id, if open (a run's actor needs the camera)."""
        with self._lock:
            camera = self._cameras.pop(env_id, None)
        if camera is not None:
            camera.jobs.put(_CLOSE)

    def close(self, timeout_s: float = 10.0) -> None:
        """Close every open env (each on its own thread); a later frame() opens the camera again."""
        with self._lock:
            cameras = list(self._cameras.values())
            self._cameras.clear()
            self._actor_checked.clear()
        for camera in cameras:
            camera.jobs.put(_CLOSE)
        deadline = time.monotonic() + timeout_s
        for camera in cameras:
            if camera.thread is not None:
                camera.thread.join(max(0.0, deadline - time.monotonic()))

    def _serve(self, camera: _Camera) -> None:
        """The camera's thread: opens the env on the first read, reads frames, closes the env when told, when
        idle, or when it cannot be opened."""
        env: gym.Env | None = None
        try:
            while True:
                try:
                    job = camera.jobs.get(timeout=self._idle_close_s)
                except queue.Empty:
                    with self._lock:  # frame() submits under this lock: no read can be left waiting
                        if not camera.jobs.empty():
                            continue
                        if self._cameras.get(camera.env_id) is camera:
                            del self._cameras[camera.env_id]
                    return
                if job is _CLOSE:
                    return
                try:
                    if env is None:
                        env = self._make(camera.env_id)
                    pixels = np.ascontiguousarray(env.unwrapped.read_camera(), dtype=np.uint8)
                    if pixels.ndim != 3 or pixels.shape[2] != 3:
                        raise ValueError(f"read_camera gave shape {pixels.shape}; expected (height, width, 3)")
                    result = CameraFrame(env_id=camera.env_id, png=encode_png(pixels), source="camera", pixels=pixels)
                except Exception as error:  # noqa: BLE001 - the robot's own failure is the answer, not a 500
                    problem = CameraUnavailable(f"{camera.env_id}: {type(error).__name__}: {error}".splitlines()[0])
                    with self._lock:
                        camera.pending = None
                        if env is None and self._cameras.get(camera.env_id) is camera:
                            del self._cameras[camera.env_id]  # the next request tries to open it afresh
                    job.set_exception(problem)
                    if env is None:
                        return
                    continue
                with self._lock:
                    camera.last, camera.pending = result, None
                job.set_result(result)
        finally:
            if env is not None:
                let_go = getattr(env.unwrapped, "let_go", None)
                if let_go is not None:  # (this process never drove the arm: closing must not hold it either)
                    let_go()
                env.close()

    def _actor_frame(self, env_id: str, store: Store) -> CameraFrame | str | None:
        """_published_frame, looked up at most every FRAME_INTERVAL_S per store and env id."""
        now, key = time.monotonic(), (id(store), env_id)
        with self._lock:
            checked = self._actor_checked.get(key)
        if checked is not None and now - checked[0] < FRAME_INTERVAL_S:
            return checked[1]
        answer = _published_frame(env_id, store)
        with self._lock:
            self._actor_checked[key] = (now, answer)
        return answer


def _published_frame(env_id: str, store: Store) -> CameraFrame | str | None:
    """The newest frame of env_id that a run's actor published, while the store lists that actor as driving its
    robot (Store.robot_runs); a reason while a run of env_id is claimed and its actor has published none yet; None
    when no run drives env_id (this server may open the camera)."""
    for robot in store.robot_runs():
        try:
            if store.get_run(run_id=robot.run_id).env_id != env_id:
                continue
            published = store.camera_frame(run_id=robot.run_id)
        except NotFound:  # the run was deleted since it was listed
            continue
        if published is None:
            return f"{env_id}: run {robot.run_id}'s actor drives this robot and has published no camera frame yet"
        return CameraFrame(env_id=env_id, png=published[0], source=f"run {robot.run_id}")
    claimed = store.claimed_run_of(env_id=env_id)
    if claimed is not None:
        return f"{env_id}: run {claimed}'s actor is taking the camera; its frames follow once it has started"
    return None


cameras = CameraSource()
"""This server's cameras, one source a process (a real camera opens once)."""


def close_cameras() -> None:
    """Close every camera this process opened (at exit; the app's lifespan may call it at shutdown)."""
    cameras.close()


atexit.register(close_cameras)


# ---------------------------------------------------------------- a photo beside the camera's frame
@dataclass(frozen=True)
class PhotoDifference:
    """One way an uploaded photo differs from the camera's frame, in plain words."""

    kind: str
    """aspect, size, colour, contrast, or viewpoint."""
    message: str


def _ratio_words(width: int, height: int) -> str:
    ratio = width / height
    for name, value in (("square", 1.0), ("4:3", 4 / 3), ("3:4", 3 / 4), ("3:2", 1.5), ("2:3", 2 / 3),
                        ("16:9", 16 / 9), ("9:16", 9 / 16)):  # fmt: skip
        if abs(ratio / value - 1) < 0.02:
            return f"{width}×{height} ({name})"
    return f"{width}×{height} ({ratio:.2f}:1)"


def _stats(image: Image.Image) -> tuple[np.ndarray, float]:
    """Per-channel means and the brightness's standard deviation of what the model sees (the centre square)."""
    pixels = np.asarray(model_view(image, STATS_SIDE), dtype=np.float64)
    brightness = pixels @ np.array([0.299, 0.587, 0.114])
    return pixels.reshape(-1, 3).mean(axis=0), float(brightness.std())


def photo_differences(photo: Image.Image, frame: np.ndarray, model_size: int) -> list[PhotoDifference]:
    """How `photo` differs from the camera's `frame` in ways that make goal photos and observations look unlike:
    shape (ASPECT_TOLERANCE), size (below the model's side, or SMALL_PHOTO_FRACTION of the frame's),
    colours (COLOUR_MEAN_TOLERANCE) and contrast (CONTRAST_RATIO_LIMIT). Empty when they look alike."""
    found: list[PhotoDifference] = []
    width, height = photo.size
    frame_height, frame_width = frame.shape[:2]
    if abs((width / height) / (frame_width / frame_height) - 1) > ASPECT_TOLERANCE:
        found.append(PhotoDifference(
            "aspect",
            f"Different shape: the photo is {_ratio_words(width, height)}, the camera's frame "
            f"{_ratio_words(frame_width, frame_height)}. The model sees the centre square of each, so they show "
            "different parts of the scene.",
        ))  # fmt: skip
    side, frame_side = min(width, height), min(frame_width, frame_height)
    if side < model_size:
        found.append(PhotoDifference(
            "size",
            f"Too small: the photo's shorter side is {side} px, less than the model's {model_size} px image, so it "
            "is enlarged and blurred.",
        ))  # fmt: skip
    elif side < SMALL_PHOTO_FRACTION * frame_side:
        found.append(PhotoDifference(
            "size",
            f"Much smaller than the camera's frame: {width}×{height} against {frame_width}×{frame_height} "
            f"(its shorter side is {round(100 * side / frame_side)}% of the camera's).",
        ))  # fmt: skip
    photo_mean, photo_spread = _stats(photo)
    frame_mean, frame_spread = _stats(Image.fromarray(frame))
    apart = [
        (name, p, f) for name, p, f in zip(CHANNELS, photo_mean, frame_mean, strict=True)
        if abs(p - f) > COLOUR_MEAN_TOLERANCE
    ]  # fmt: skip
    if apart:
        signs = {p > f for _, p, f in apart}
        overall = (
            "the photo is much brighter" if signs == {True} and len(apart) == 3
            else "the photo is much darker" if signs == {False} and len(apart) == 3
            else "the photo has another colour cast"
        )  # fmt: skip
        channels = ", ".join(f"{name} {p:.0f} against {f:.0f}" for name, p, f in apart)
        found.append(PhotoDifference(
            "colour",
            f"Different colours: {overall} (average {channels}, of 255; more than {COLOUR_MEAN_TOLERANCE:.0f} apart).",
        ))  # fmt: skip
    ratio = (photo_spread + 1.0) / (frame_spread + 1.0)
    if ratio > CONTRAST_RATIO_LIMIT or ratio < 1 / CONTRAST_RATIO_LIMIT:
        how = "harsher" if ratio > 1 else "flatter"
        found.append(PhotoDifference(
            "contrast",
            f"Different contrast: the photo's light is {how} (brightness spread {photo_spread:.0f} against the "
            f"camera's {frame_spread:.0f}).",
        ))  # fmt: skip
    return found


def viewpoint_difference(photo: Image.Image, set_photos: list[Image.Image]) -> PhotoDifference | None:
    """The photo is from another viewpoint than the set's other photos: its edges run elsewhere than theirs
    (contract.images.viewpoint_similarity below VIEWPOINT_SIMILARITY), whatever its brightness. None when it looks
    like them, or the set has too few photos to tell."""
    similarity = viewpoint_similarity(photo, set_photos)
    if similarity is None or similarity >= VIEWPOINT_SIMILARITY:
        return None
    return PhotoDifference(
        "viewpoint",
        f"Another viewpoint: the photo's edges and shapes are unlike those of the set's {len(set_photos)} other "
        f"photos (structure similarity {similarity:.2f}, below {VIEWPOINT_SIMILARITY:.2f}). Take goal photos from "
        "the robot camera's point of view.",
    )
