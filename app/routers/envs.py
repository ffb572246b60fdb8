"""Envs: the ids a run may name (the known ones, for the New run form's suggestions) and a first-frame preview of
one (the observation as the model sees it and the display render; app.previews makes and keeps them), only for an
env id the allowlist permits (RAQ_ENV_MODULES, see README Security) and at a size from PREVIEW_SIZES."""

from typing import Annotated, Literal
from urllib.parse import urlencode

from fastapi import APIRouter, HTTPException, Query, Response
from pydantic import AfterValidator, BaseModel

from app.deps import ReadAuth, SameSiteRead, SettingsDep
from app.previews import PREVIEW_SIZES, preview_frames, suggested_env_ids
from app.schemas import TaskSettingsOut, errors
from app.views import task_settings_out
from contract.envs import (
    SIM_ENV_IDS,
)
from contract.settings import Settings

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
