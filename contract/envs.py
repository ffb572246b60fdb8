"""Making any image env: a gymnasium id, or "module:EnvId" (the module is imported first, so it can register).

Only modules the operator lists in RAQ_ENV_MODULES (and their submodules) are ever imported for an env, besides
the project's own `sim`: the server refuses any other env id when the run is created (`env_id_problem`), and
the learner checks again before it imports anything (`_import_for`).

The env's observation must be an RGB image (HWC or CHW; uint8, or float in [0, 1], finite), or a dict holding
one under "image" or "pixels" (`observation_problem` is the check; anything else fails the run at once).
Observations of another size are resized to image_size. info["success"] is used when the env reports it
(evaluation success rate, sparse reward, ground truth on queries) and is optional.
"""

import contextlib
import difflib
import importlib
import io
import json
import math
import os
import subprocess
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import gymnasium as gym
import numpy as np
from PIL import Image

import sim


@dataclass(frozen=True)
class TaskSettings:
    """The training-config fields a simulated task starts from (sim.PRESETS; every other field: its default)."""

    fields: dict[str, int | float]
    """Field name -> value, as a run's config takes them."""
    results_page: str
    """Where the docs show how well the task learns with them."""


# The New run form fills these in when a task is picked; GET /api/envs lists them. A run created through the API
# gets what it is sent, so an oracle or script passes them itself.
SIM_TASK_SETTINGS: dict[str, TaskSettings] = {
    env_id: TaskSettings(dict(fields), f"docs/results.md#{task}")
    for task, env_id in sim.TASKS.items()
    for fields in (sim.PRESETS[env_id],)
}
SIM_ENV_IDS = tuple(SIM_TASK_SETTINGS)
ALWAYS_ALLOWED_MODULES = ("sim", "robot")  # the project's own simulated tasks and stand-in robot


class EnvNotAllowed(ValueError):
    """An env id that names a module the operator has not allowed, or an id that is not registered."""


def allowed_env_modules() -> tuple[str, ...]:
    """RAQ_ENV_MODULES, read like every other setting (the learner has no other channel from the operator)."""
    from contract.settings import get_settings  # noqa: PLC0415 - settings are read when an env is made, not at import

    return get_settings().env_modules


def module_allowed(module: str, allowed: Iterable[str]) -> bool:
    """A listed module, or a submodule of a listed package."""
    return any(module == name or module.startswith(name + ".") for name in (*ALWAYS_ALLOWED_MODULES, *allowed))


_FRESH_REGISTRY = """
import importlib, json, sys
import gymnasium
import contract.envs
if sys.argv[1]:
    importlib.import_module(sys.argv[1])
print(json.dumps(sorted(gymnasium.registry)))
"""


@lru_cache(maxsize=64)
def ids_a_learner_can_make(module: str | None = None) -> frozenset[str]:
    """The env ids a fresh learner can make: registered in a new interpreter once it has imported what every
    learner imports (gymnasium and the simulated tasks) and, with `module`, that module too. Asked of a new
    interpreter, not of this process's registry, which holds whatever any module imported here registered.
    Raises ImportError when the module cannot be imported."""
    paths = os.pathsep.join(path for path in sys.path if path)
    result = subprocess.run(
        [sys.executable, "-c", _FRESH_REGISTRY, module or ""], capture_output=True, text=True, timeout=120,
        env={**os.environ, "PYTHONPATH": paths}, check=False,
    )  # fmt: skip
    lines = result.stdout.strip().splitlines()
    if result.returncode != 0 or not lines:
        error = next((line for line in reversed(result.stderr.splitlines()) if line.strip()), "no output")
        raise ImportError(f"importing {module or 'gymnasium'!r} failed: {error.strip()[:300]}")
    return frozenset(json.loads(lines[-1]))


def known_env_ids() -> list[str]:
    """The bare ids a fresh learner can make: gymnasium's own and the simulated tasks."""
    return sorted(ids_a_learner_can_make(None) | set(SIM_ENV_IDS))


def module_env_ids(module: str) -> list[str]:
    """The ids importing `module` registers (beyond gymnasium's and the simulated tasks), as "module:EnvId"."""
    return [f"{module}:{name}" for name in sorted(ids_a_learner_can_make(module) - ids_a_learner_can_make(None))]


def env_id_problem(env_id: str, *, allowed_modules: Iterable[str]) -> str | None:
    """Why env_id cannot be used here (with suggestions for a near miss), or None when it can. A plain id must
    be one a fresh learner can make (gymnasium's own or a simulated task); "module:EnvId" must name an allowed
    module whose import registers EnvId. Modules imported earlier in this process count for neither."""
    allowed = tuple(allowed_modules)
    if env_id.count(":") > 1:
        return f"{env_id!r}: at most one ':' (module:EnvId)"
    if ":" in env_id:
        module, name = env_id.split(":", 1)
        if not module or not name:
            return f"{env_id!r}: write module:EnvId"
        if module_allowed(module, allowed):
            try:
                registered = ids_a_learner_can_make(module)
            except (ImportError, subprocess.SubprocessError, ValueError) as error:
                return f"{env_id!r}: {error}"
            if name in registered:
                return None
            own = sorted(registered - ids_a_learner_can_make(None))
            close = difflib.get_close_matches(name, own, n=3, cutoff=0.6)
            hint = f"; did you mean {' or '.join(repr(f'{module}:{m}') for m in close)}?" if close else ""
            return f"{env_id!r}: importing {module!r} does not register {name!r}{hint}"
        listed = ", ".join(allowed) if allowed else "none"
        close = difflib.get_close_matches(module, [*ALWAYS_ALLOWED_MODULES, *allowed], n=3, cutoff=0.6)
        hint = f"; did you mean {' or '.join(repr(f'{m}:{name}') for m in close)}?" if close else ""
        return f"module {module!r} is not one the operator allows for envs (RAQ_ENV_MODULES lists: {listed}){hint}"
    known = known_env_ids()
    if env_id in known:
        return None
    if env_id in gym.registry:  # registered here by a module this process imported, which a learner would not
        for module in allowed:
            with contextlib.suppress(ImportError, subprocess.SubprocessError, ValueError):
                if env_id in ids_a_learner_can_make(module):
                    return (
                        f"{env_id!r} is registered by {module!r}: name it {module}:{env_id} (a learner imports "
                        "the module only when the id names it)"
                    )
        return (
            f"{env_id!r} is registered only in this server, by a module a learner does not import; name it as "
            "module:EnvId"
        )
    close = difflib.get_close_matches(env_id, known, n=3, cutoff=0.6)
    hint = f"; did you mean {' or '.join(map(repr, close))}?" if close else ""
    return f"{env_id!r} is not a registered gymnasium id{hint}"


def _import_for(env_id: str) -> str:
    """Import what registers env_id, if its module is allowed; return the id to pass to gymnasium.make."""
    if ":" in env_id:
        module, name = env_id.split(":", 1)
        if ":" in name or not module_allowed(module, allowed_env_modules()):
            raise EnvNotAllowed(
                f"env {env_id!r}: module {module!r} is not in RAQ_ENV_MODULES, so this learner does not import it"
            )
        importlib.import_module(module)
        return name
    if env_id not in gym.registry and env_id in SIM_ENV_IDS:
        importlib.import_module("sim")
    return env_id


def env_class(env_id: str) -> type | None:
    """The class an env id's registration makes (its module imported if allowed), without making the env; None
    when the entry point is not a class."""
    entry_point = gym.spec(_import_for(env_id)).entry_point
    if isinstance(entry_point, str):
        module, _, name = entry_point.partition(":")
        entry_point = getattr(importlib.import_module(module), name, None)
    return entry_point if isinstance(entry_point, type) else None


def make_env(env_id: str, *, image_size: int, display_size: int) -> gym.Env:
    """The env with render_mode="rgb_array"; image_size / render_size are passed when the env takes them."""
    name = _import_for(env_id)
    attempts: list[dict[str, Any]] = [
        {"render_mode": "rgb_array", "image_size": image_size, "render_size": display_size},
        {"render_mode": "rgb_array", "image_size": image_size},
        {"render_mode": "rgb_array"},
        {},
    ]
    error: Exception | None = None
    for kwargs in attempts:
        try:
            return gym.make(name, **kwargs)
        except TypeError as exc:  # the env does not take one of these keyword arguments
            error = exc
    raise ValueError(f"cannot make env {env_id!r}: {error}")


def check_action_space(env: gym.Env) -> gym.spaces.Box:
    space = env.action_space
    if not isinstance(space, gym.spaces.Box) or len(space.shape) != 1:
        raise ValueError(f"the env's action space must be a 1-D Box, not {space}")
    if not (np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))):
        raise ValueError("the env's action space must be bounded")
    return space


def scale_action(action: np.ndarray, space: gym.spaces.Box) -> np.ndarray:
    """[-1, 1] (the tanh policy's range) -> [low, high]."""
    low, high = space.low, space.high
    return (low + (action + 1.0) * 0.5 * (high - low)).astype(space.dtype)


class BadObservation(ValueError):
    """An observation that is not an image the networks can take (observation_problem says why)."""


IMAGE_RULE = "an image must be H x W x 3 (or 3 x H x W), uint8, or float in [0, 1]"


def _image_array(image: Any) -> tuple[np.ndarray | None, str | None]:
    """The observation's image as an array in HWC with 3 or 4 channels, or None and why it is not one."""
    if isinstance(image, dict):
        for key in ("image", "pixels", "rgb"):
            if key in image:
                return _image_array(image[key])
        return None, f"observation is a dict without an 'image' or 'pixels' key ({sorted(map(str, image))})"
    try:
        array = np.asarray(image)
    except Exception as error:  # noqa: BLE001 - a ragged list, an object numpy cannot take
        return None, f"observation is not an array ({type(error).__name__}); {IMAGE_RULE}"
    if array.dtype != np.uint8 and not np.issubdtype(array.dtype, np.floating):
        what = type(image).__name__ if array.dtype.kind in "OUSV" else f"dtype {array.dtype}"
        return None, f"observation is {what}, not an image; {IMAGE_RULE}"
    if array.ndim == 3 and array.shape[0] in (3, 4) and array.shape[-1] not in (3, 4):
        array = array.transpose(1, 2, 0)
    if array.ndim != 3 or array.shape[-1] not in (3, 4) or 0 in array.shape:
        return None, f"observation has shape {array.shape}, not an RGB image; {IMAGE_RULE}"
    return array, None


def observation_problem(observation: Any) -> str | None:
    """Why the env's observation is not an image the networks can take, or None when it is one: an RGB image
    (H x W x 3, or 3 x H x W; a fourth, alpha channel is dropped; or a dict holding one under "image" or
    "pixels"), uint8 or float in [0, 1], with no NaN or infinite values. The one check the server's env preview
    (at run creation) and the learner (on every observation it converts) make."""
    return _checked_array(observation)[1]


def _checked_array(observation: Any) -> tuple[np.ndarray | None, str | None]:
    """The observation's HWC image array and None, or None and observation_problem's reason (read once)."""
    array, problem = _image_array(observation)
    if array is None or array.dtype == np.uint8:
        return array, problem
    if not np.isfinite(array).all():
        return None, "observation has NaN values" if np.isnan(array).any() else "observation has infinite values"
    low, high = float(array.min()), float(array.max())
    if low < 0.0 or high > 1.0:
        return None, f"observation is float with values from {low:g} to {high:g}; a float image must be in [0, 1]"
    return array, None


def as_rgb(image: Any, env_id: str = "the env") -> np.ndarray:
    """An image the env gives (observation_problem finds nothing wrong with it) -> uint8 HWC; else BadObservation."""
    array, problem = _checked_array(image)
    if array is None:
        raise BadObservation(f"{env_id}: {problem}")
    array = array[..., :3]
    if array.dtype != np.uint8:
        array = (array.astype(np.float32) * 255.0).round().astype(np.uint8)
    return np.ascontiguousarray(array)


def resize(image: np.ndarray, size: int) -> np.ndarray:
    """uint8 HWC -> (size, size, 3); unchanged when already that size."""
    if image.shape[0] == size and image.shape[1] == size:
        return image
    return np.array(Image.fromarray(image).resize((size, size), Image.Resampling.BILINEAR, reducing_gap=None))


def model_image(observation: Any, image_size: int, env_id: str = "the env") -> np.ndarray:
    """The env's observation as the networks see it: uint8 (image_size, image_size, 3); BadObservation naming
    env_id when it is not an image (observation_problem)."""
    return resize(as_rgb(observation, env_id), image_size)


def display_image(env: gym.Env, size: int, fallback: np.ndarray | None) -> np.ndarray:
    """env.render() of the current state, longer side `size`; the upscaled observation if it cannot render. Before
    the env's first reset (gymnasium's order check refuses render then) the env itself renders what it sees: a
    person looks at the scene while resetting it, before the first episode too. ValueError when nothing renders
    and there is no observation to fall back on."""
    try:
        frame = env.render()
    except gym.error.ResetNeeded:  # a look before the first reset: the env's own render, past the order check
        try:
            frame = env.unwrapped.render()
        except Exception:
            frame = None
    except Exception:  # an env without rgb_array rendering
        frame = None
    if frame is None:
        if fallback is None:
            raise ValueError("the env renders nothing and has shown no observation yet")
        return resize(fallback, size)
    frame = as_rgb(frame)
    height, width = frame.shape[:2]
    if max(height, width) != size:
        scale = size / max(height, width)
        new = (max(1, round(width * scale)), max(1, round(height * scale)))
        frame = np.array(Image.fromarray(frame).resize(new, Image.Resampling.BILINEAR))
    return frame


def snapshot_of(env: gym.Env) -> Any | None:
    """The env's state snapshot when it can take one (`state_snapshot()` / `restore_snapshot(s)` on the unwrapped
    env, as the simulated tasks have), else None."""
    unwrapped = env.unwrapped
    if hasattr(unwrapped, "state_snapshot") and hasattr(unwrapped, "restore_snapshot"):
        return unwrapped.state_snapshot()
    return None


def display_of_snapshot(env: gym.Env, snapshot: Any, size: int, fallback: np.ndarray) -> np.ndarray:
    """`display_image` of the state `snapshot` was taken of; the env is left in the state it was in."""
    unwrapped = env.unwrapped
    current = unwrapped.state_snapshot()
    unwrapped.restore_snapshot(snapshot)
    try:
        return display_image(env, size, fallback)
    finally:
        unwrapped.restore_snapshot(current)


def success_of(info: dict[str, Any]) -> float | None:
    """The env's ground-truth success flag as 0.0 / 1.0, or None when it reports none."""
    value = info.get("success") if isinstance(info, dict) else None
    if value is None:
        return None
    return float(bool(np.asarray(value).item()))


def jsonable(value: Any) -> Any:
    """info values as JSON (numpy scalars and arrays to Python); what cannot be is dropped."""
    if isinstance(value, dict):
        out = {str(k): jsonable(v) for k, v in value.items()}
        return {k: v for k, v in out.items() if v is not _DROP}
    if isinstance(value, (list, tuple)):
        return [v for v in (jsonable(v) for v in value) if v is not _DROP]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist()) if value.size <= 64 else _DROP
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return _DROP


_DROP = object()


def encode_png(image: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    return buffer.getvalue()


def decode_image(data: bytes, image_size: int) -> np.ndarray:
    """PNG/JPEG bytes -> uint8 (image_size, image_size, 3)."""
    with Image.open(io.BytesIO(data)) as image:
        rgb = np.array(image.convert("RGB"))
    return resize(rgb, image_size)


def encode_gif(frames: list[np.ndarray], frame_ms: int = 80) -> bytes:
    """An animated GIF, each frame on its own 256-colour palette. Fast octree without dithering: PIL's default
    (median cut, Floyd-Steinberg) took 5.8 ms a 128 px frame, a quarter of an evaluation; this takes 0.7 ms and
    is off by ~1/255 per channel on average."""
    images = [
        Image.fromarray(frame).quantize(colors=256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE)
        for frame in frames
    ]
    buffer = io.BytesIO()
    images[0].save(buffer, format="GIF", save_all=True, append_images=images[1:], duration=frame_ms, loop=0)
    return buffer.getvalue()


def first_frames(env_id: str, *, image_size: int, display_size: int, seed: int = 0) -> tuple[bytes, bytes, str]:
    """The env's first observation after reset(seed) as the networks see it and its display render, as PNGs, and a
    line about the env (action space, whether it reports success). Gymnasium only, no torch: the server calls it
    for the New run form's preview and the goal-set page's camera view (only for env ids env_id_problem allows)."""
    env = make_env(env_id, image_size=image_size, display_size=display_size)
    try:
        observation, info = env.reset(seed=seed)
        image = model_image(observation, image_size, env_id)
        display = display_image(env, display_size, image)
        space = env.action_space
        success = "reports success" if success_of(info) is not None else "reports no success (no ground truth)"
        return encode_png(image), encode_png(display), f"action space {space}; {success}"
    finally:
        env.close()
