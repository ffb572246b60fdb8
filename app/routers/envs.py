"""Envs: the ids a run may name (the known ones, for the New run form's suggestions) and a first-frame preview of
one (the observation as the model sees it and the display render), made with gymnasium in this process (no torch)
and only for an env id the allowlist permits (RAQ_ENV_MODULES, see README Security)."""

import threading
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache
from typing import Annotated, Literal
from urllib.parse import urlencode

from fastapi import APIRouter, HTTPException, Query, Response
from pydantic import AfterValidator, BaseModel

from app.deps import ReadAuth, SameSiteRead, SettingsDep
from app.schemas import errors
from contract.envs import (
    SIM_ENV_IDS,
    SIM_TASK_SETTINGS,
    BadObservation,
    env_id_problem,
    first_frames,
    module_env_ids,
)
from contract.settings import Settings

router = APIRouter(prefix="/api/envs", tags=["envs"], responses=errors(401))

PREVIEW_SIZES = (16, 24, 32, 40, 48, 56, 64, 72, 80, 84, 96, 112, 128, 160, 192, 224, 256)
"""The model image sizes a preview is made at: a bounded set, so that callers cannot make the server build and keep
one env per size they invent."""
PREVIEW_CACHE_ENTRIES = 24
"""First frames kept (a few KB of PNG each); the least recently used goes first."""
DISPLAY_SIZE = 256


class TaskSettingsOut(BaseModel):
    fields: dict[str, int | float]
    results_page: str


class EnvsOut(BaseModel):
    simulated: list[str]
    registered: list[str]
    """The other envs a run can be made of: the allowed modules' envs whose preview works (image observations),
    as module:EnvId. Gymnasium's own ids (no image observations) are not suggested."""
    allowed_modules: list[str]
    task_settings: dict[str, TaskSettingsOut]
    """Per simulated task: the config fields a run of it starts from (the New run form fills them in)."""


class EnvPreviewOut(BaseModel):
    env_id: str
    observation_url: str
    display_url: str
    description: str


@router.get("", response_model=EnvsOut)
def list_envs(settings: SettingsDep, _auth: ReadAuth) -> EnvsOut:
    """The simulated tasks with the settings a run of each starts from, the allowed modules' image envs (those
    whose preview works, as `module:EnvId`), and the modules runs may name as `module:EnvId`."""
    return EnvsOut(
        simulated=list(SIM_ENV_IDS), registered=suggested_env_ids(settings), allowed_modules=list(settings.env_modules),
        task_settings=task_settings_out(),
    )  # fmt: skip


def task_settings_out() -> dict[str, TaskSettingsOut]:
    """SIM_TASK_SETTINGS as the API and the New run page serve it."""
    return {
        env_id: TaskSettingsOut.model_validate(task, from_attributes=True) for env_id, task in SIM_TASK_SETTINGS.items()
    }


class FirstFrames:
    """A bounded cache of first frames by (env id, size). Every env is made on one thread of its own, one at a time:
    a rendering context (EGL, OSMesa) stays with the thread that made it, so envs made on the request threads kept
    about 12 MB each of up to 40 threads. Callers who wait while frames are made get the one result: 80 callers at
    once make each env once, not 80 times."""

    def __init__(self, entries: int) -> None:
        self.entries = entries
        self._made: OrderedDict[tuple[str, int], tuple[bytes, bytes, str]] = OrderedDict()
        self._lock = threading.Lock()
        self._maker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="env-preview")

    def get(self, env_id: str, size: int) -> tuple[bytes, bytes, str]:
        key = (env_id, size)
        with self._lock:
            if key in self._made:
                self._made.move_to_end(key)
                return self._made[key]
            made = self._maker.submit(first_frames, env_id, image_size=size, display_size=DISPLAY_SIZE)
            frames = made.result()  # (an error is raised here, and not kept)
            self._made[key] = frames
            while len(self._made) > self.entries:
                self._made.popitem(last=False)
            return frames


_first_frames = FirstFrames(PREVIEW_CACHE_ENTRIES)


def preview_size(size: int) -> int:
    """The listed preview size nearest to a run's image size (its env is checked at that size)."""
    return min(PREVIEW_SIZES, key=lambda listed: (abs(listed - size), listed))


def _listed_size(size: int) -> int:
    if size not in PREVIEW_SIZES:
        raise ValueError(f"must be one of {', '.join(map(str, PREVIEW_SIZES))}")
    return size


EnvIdQuery = Annotated[str, Query(min_length=1, max_length=200, description="A registered id or module:EnvId.")]
SizeQuery = Annotated[
    int,
    Query(
        description=f"The model's image size, one of {', '.join(map(str, PREVIEW_SIZES))}.",
        json_schema_extra={"enum": list(PREVIEW_SIZES)},
    ),
    AfterValidator(_listed_size),
]


def _env_error(message: str) -> HTTPException:
    return HTTPException(status_code=422, detail=[{"loc": ["query", "env_id"], "msg": message, "type": "value_error"}])


def preview_frames(env_id: str, size: int, settings: Settings) -> tuple[bytes, bytes, str] | str:
    """The env's first frames and description (as the preview shows them), or why a run of it cannot start: an
    id that is not allowed or registered, an env that cannot be made or reset, or an observation that is not an
    image (contract.envs.observation_problem: "<env id>: observation has NaN values"). The New run form's preview
    and run creation both ask this, so a run is created only of an env whose preview works."""
    problem = env_id_problem(env_id, allowed_modules=settings.env_modules)
    if problem:
        return problem
    try:
        return _first_frames.get(env_id, preview_size(size))
    except BadObservation as error:
        return str(error)[:500]
    except Exception as error:  # noqa: BLE001 - any failure of the env itself is the user's answer, not a 500
        return f"cannot make or reset {env_id!r}: {type(error).__name__}: {error}".splitlines()[0][:500]


def preview_problem(env_id: str, size: int, settings: Settings) -> str | None:
    """preview_frames's reason, or None when the env previews fine."""
    frames = preview_frames(env_id, size, settings)
    return frames if isinstance(frames, str) else None


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


def _checked_frames(env_id: str, size: int, settings: Settings) -> tuple[bytes, bytes, str]:
    frames = preview_frames(env_id, size, settings)
    if isinstance(frames, str):
        raise _env_error(frames)
    return frames


@router.get("/preview", response_model=EnvPreviewOut, responses=errors(403))
def preview(
    env_id: EnvIdQuery, settings: SettingsDep, _auth: ReadAuth, _same_site: SameSiteRead, size: SizeQuery = 48
) -> EnvPreviewOut:
    """Make the env, reset it with seed 0 and describe it; the two images are at the URLs given (422 when the id
    is not allowed or the env cannot be made)."""
    _image, _display, description = _checked_frames(env_id, size, settings)
    base = "/api/envs/preview/image?" + urlencode({"env_id": env_id, "size": size})
    return EnvPreviewOut(
        env_id=env_id, observation_url=base + "&kind=observation", display_url=base + "&kind=display",
        description=description,
    )  # fmt: skip


@router.get(
    "/preview/image",
    response_class=Response,
    responses={200: {"content": {"image/png": {}}, "description": "The first frame."}, **errors(403)},
)
def preview_image(
    env_id: EnvIdQuery,
    settings: SettingsDep,
    _auth: ReadAuth,
    _same_site: SameSiteRead,
    size: SizeQuery = 48,
    kind: Literal["observation", "display"] = "observation",
) -> Response:
    image, display, _description = _checked_frames(env_id, size, settings)
    return Response(content=image if kind == "observation" else display, media_type="image/png")
