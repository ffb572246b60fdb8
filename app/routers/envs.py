"""Envs: the ids a run may name (the known ones, for the New run form's suggestions) and a first-frame preview of
one (the observation as the model sees it and the display render; app.previews makes and keeps them), only for an
env id the allowlist permits (RAQ_ENV_MODULES, see README Security) and at a size from PREVIEW_SIZES."""

from typing import Annotated, Literal
from urllib.parse import urlencode

from fastapi import APIRouter, HTTPException, Query, Response
from pydantic import AfterValidator, BaseModel

from app.deps import ReadAuth, SameSiteRead, SettingsDep, StoreDep
from app.previews import PREVIEW_SIZES, preview_frames, suggested_env_ids
from app.schemas import TaskSettingsOut, errors
from app.views import task_settings_out
from contract.config import DEVICE_PATTERN, robot_preset_for
from contract.envs import SIM_ENV_IDS, env_id_problem
from contract.settings import Settings
from contract.store import Store
from robot.base import control_rate

router = APIRouter(prefix="/api/envs", tags=["envs"], responses=errors(401))


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


class RobotSettingsOut(BaseModel):
    env_id: str
    control_hz: float
    """The env's real-time rate (steps a second); 0: not a robot env, it runs in lockstep and has no robot preset."""
    device: str
    preset: str | None
    """The TrainConfig robot preset for a learner on `device` ("cpu_robot", "real_robot"); None for 0 Hz."""
    fields: dict[str, int | float]
    """The fields the preset sets (the New run form fills them in)."""
    description: str


def _device(device: str) -> str:
    if not DEVICE_PATTERN.fullmatch(device):
        raise ValueError('must be "cpu", "cuda" or "cuda:N"')
    return device


DeviceQuery = Annotated[
    str, Query(max_length=8, description='The learner\'s device: "cpu", "cuda" or "cuda:N".'), AfterValidator(_device)
]


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


def _checked_frames(env_id: str, size: int, settings: Settings, store: Store) -> tuple[bytes, bytes, str]:
    frames = preview_frames(env_id, size, settings, store)
    if isinstance(frames, str):
        raise _env_error(frames)
    return frames


@router.get("/robot-settings", response_model=RobotSettingsOut)
def robot_settings(
    env_id: EnvIdQuery, settings: SettingsDep, _auth: ReadAuth, device: DeviceQuery = "cpu"
) -> RobotSettingsOut:
    """The robot settings a run of this env starts from on `device`: for a robot env (one with a real-time rate),
    TrainConfig.cpu_robot()'s fields on "cpu" and the paper's TrainConfig.real_robot() on "cuda"; none for any
    other env (422 when the id is not allowed or the env's class cannot be read)."""
    problem = env_id_problem(env_id, allowed_modules=settings.env_modules)
    if problem:
        raise _env_error(problem)
    try:
        rate = control_rate(env_id)
    except Exception as error:  # noqa: BLE001 - a module that fails to import is the user's answer, not a 500
        message = f"cannot read {env_id!r}'s class: {type(error).__name__}: {error}"
        raise _env_error(message.splitlines()[0][:500]) from error
    if rate <= 0:
        return RobotSettingsOut(env_id=env_id, control_hz=0.0, device=device, preset=None, fields={}, description="")
    preset = robot_preset_for(device)
    return RobotSettingsOut(
        env_id=env_id, control_hz=rate, device=device, preset=preset.name, fields=preset.fields,
        description=preset.description,
    )  # fmt: skip


@router.get("/preview", response_model=EnvPreviewOut, responses=errors(403))
def preview(
    env_id: EnvIdQuery,
    settings: SettingsDep,
    store: StoreDep,
    _auth: ReadAuth,
    _same_site: SameSiteRead,
    size: SizeQuery = 48,
) -> EnvPreviewOut:
    """Make the env, reset it with seed 0 and describe it; a robot env is never made or reset: its camera's current
    frame is shown. The two images are at the URLs given (422 when the id is not allowed, the env cannot be made
    or the robot's camera gives no frame)."""
    _image, _display, description = _checked_frames(env_id, size, settings, store)
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
    store: StoreDep,
    _auth: ReadAuth,
    _same_site: SameSiteRead,
    size: SizeQuery = 48,
    kind: Literal["observation", "display"] = "observation",
) -> Response:
    image, display, _description = _checked_frames(env_id, size, settings, store)
    return Response(content=image if kind == "observation" else display, media_type="image/png")
