"""Goal sets and their goal photos: create, upload (one or several at once), list, images, delete; goals from
the robot's own camera (its live frame, Capture) and the check of a photo against that camera (app.camera)."""

import io
from datetime import UTC, datetime
from pathlib import PurePosixPath, PureWindowsPath
from typing import Annotated, Any, Literal
from urllib.parse import urlencode

from fastapi import APIRouter, File, HTTPException, Query, Response, UploadFile, status
from PIL import Image

from app.camera import (
    CameraFrame,
    CameraUnavailable,
    PhotoDifference,
    camera_env_ids,
    cameras,
    photo_differences,
    viewpoint_difference,
)
from app.deps import GoalExampleId, GoalSetId, ReadAuth, SameSiteRead, SettingsDep, StoreDep, WriteAuth
from app.schemas import (
    WRITE_ERRORS,
    CameraFrameInfo,
    CameraOut,
    CamerasOut,
    CaptureCreate,
    ErrorOut,
    GoalExampleOut,
    GoalSetCreate,
    GoalSetDetail,
    GoalSetOut,
    PhotoCheckOut,
    PhotoInfo,
    PhotoWarningOut,
    UploadedGoalExampleOut,
    errors,
    row_with,
)
from contract.envs import SIM_ENV_IDS, module_allowed
from contract.images import ImageRejected, PreparedImage, decode_upload, prepare_upload
from contract.settings import Settings
from contract.store import GoalSet, Store
from robot.base import robot_class

router = APIRouter(tags=["goal sets"], responses=errors(401))

IMAGE_CACHE = {"Cache-Control": "private, max-age=86400"}  # an example's pixels never change
MAX_FILES_PER_UPLOAD = 100
# Room for each part's boundary and headers (a 255-character file name included) and the closing boundary.
MULTIPART_OVERHEAD_PER_FILE = 4 * 1024
MULTIPART_OVERHEAD = 64 * 1024


def upload_request_limit(max_file_bytes: int) -> int:
    """The largest whole upload request: MAX_FILES_PER_UPLOAD files at the per-file limit, plus multipart framing.
    app.security.RequestGuard refuses a bigger request (413) before it is read."""
    return MAX_FILES_PER_UPLOAD * (max_file_bytes + MULTIPART_OVERHEAD_PER_FILE) + MULTIPART_OVERHEAD


def _clean_filename(name: str | None, index: int) -> str:
    base = PureWindowsPath(PurePosixPath(name or "").name).name.strip()
    return base[:255] or f"upload-{index + 1}"


@router.post(
    "/api/goal-sets",
    status_code=status.HTTP_201_CREATED,
    response_model=GoalSetOut,
    responses=errors(400, 409, *WRITE_ERRORS),
)
def create_goal_set(body: GoalSetCreate, store: StoreDep, _auth: WriteAuth) -> GoalSetOut:
    """env_id: the task the photos show ("Start a run with this set" opens it; a run of another task is refused
    unless confirmed)."""
    goal_set = store.create_goal_set(name=body.name, image_size=body.image_size, env_id=body.env_id)
    return GoalSetOut.model_validate(row_with(goal_set, example_count=0), from_attributes=True)


@router.get("/api/goal-sets", response_model=list[GoalSetOut])
def list_goal_sets(store: StoreDep, _auth: ReadAuth) -> list[GoalSetOut]:
    return [
        GoalSetOut.model_validate(row_with(goal_set, example_count=count), from_attributes=True)
        for goal_set, count in store.list_goal_sets()
    ]


@router.get("/api/goal-sets/{goal_set_id}", response_model=GoalSetDetail, responses=errors(404))
def get_goal_set(goal_set_id: GoalSetId, store: StoreDep, _auth: ReadAuth) -> GoalSetDetail:
    goal_set = store.get_goal_set(goal_set_id=goal_set_id)
    examples = store.list_goal_examples(goal_set_id=goal_set_id)
    return GoalSetDetail.model_validate(
        row_with(goal_set, example_count=len(examples), examples=examples), from_attributes=True
    )


@router.delete(
    "/api/goal-sets/{goal_set_id}", status_code=status.HTTP_204_NO_CONTENT, responses=errors(404, *WRITE_ERRORS)
)
def delete_goal_set(goal_set_id: GoalSetId, store: StoreDep, _auth: WriteAuth) -> Response:
    """Deletes the set and its photos; runs that used it keep running with what their learner loaded."""
    store.delete_goal_set(goal_set_id=goal_set_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.get("/api/goal-sets/{goal_set_id}/examples", response_model=list[GoalExampleOut], responses=errors(404))
def list_goal_examples(goal_set_id: GoalSetId, store: StoreDep, _auth: ReadAuth) -> list[GoalExampleOut]:
    store.get_goal_set(goal_set_id=goal_set_id)
    return [
        GoalExampleOut.model_validate(example, from_attributes=True)
        for example in store.list_goal_examples(goal_set_id=goal_set_id)
    ]


@router.post(
    "/api/goal-sets/{goal_set_id}/examples",
    status_code=status.HTTP_201_CREATED,
    response_model=list[UploadedGoalExampleOut],
    responses={
        **errors(404, *WRITE_ERRORS),
        400: {"model": ErrorOut, "description": "A file is not a usable image"},
        413: {
            "model": ErrorOut,
            "description": f"A file, the request, or the number of files (over {MAX_FILES_PER_UPLOAD}) is too large",
        },
    },
    # The form parser stops at the first file past the cap (400) instead of spooling the rest.
    form_limits={"max_files": MAX_FILES_PER_UPLOAD},
)
def upload_goal_examples(
    goal_set_id: GoalSetId,
    files: Annotated[list[UploadFile], File(description="One or several PNG, JPEG or WebP photos of success.")],
    store: StoreDep,
    settings: SettingsDep,
    _auth: WriteAuth,
) -> list[UploadedGoalExampleOut]:
    """Every file is checked before any is stored: one bad file rejects the whole upload. When the set's task is a
    robot env with a camera, each stored photo carries `warnings`: how it differs from the camera's current frame
    (advisory, as POST …/photo-check says; the photo is stored all the same)."""
    goal_set = store.get_goal_set(goal_set_id=goal_set_id)
    if not files:
        raise HTTPException(status_code=400, detail="no files were uploaded")
    if len(files) > MAX_FILES_PER_UPLOAD:
        raise HTTPException(
            status_code=413,
            detail=f"{len(files)} files in one upload; the limit is {MAX_FILES_PER_UPLOAD} "
            "(send them in several uploads; nothing from this upload was stored)",
        )
    total_limit = upload_request_limit(settings.max_upload_bytes)
    total = 0
    prepared: list[PreparedImage] = []
    for index, upload in enumerate(files):
        filename = _clean_filename(upload.filename, index)
        data = upload.file.read(settings.max_upload_bytes + 1)
        total += len(data)
        if total > total_limit:
            raise HTTPException(
                status_code=413,
                detail=f"the upload is over {total_limit:,} bytes in all (nothing from this upload was stored)",
            )
        try:
            prepared.append(
                prepare_upload(
                    data,
                    filename=filename,
                    model_size=goal_set.image_size,
                    max_bytes=settings.max_upload_bytes,
                    max_pixels=settings.max_image_pixels,
                )
            )
        except ImageRejected as error:
            raise HTTPException(
                status_code=error.status_code, detail=f"{error.message} (nothing from this upload was stored)"
            ) from None
    stored = [
        store.add_goal_example(
            goal_set_id=goal_set_id,
            filename=image.filename,
            original=image.original,
            original_media_type=image.media_type,
            width=image.width,
            height=image.height,
            model_png=image.model_png,
            display_png=image.display_png,
        )
        for image in prepared
    ]
    frame = _set_camera_frame(goal_set, settings, store)
    set_photos = _set_photos(store, goal_set_id)
    return [
        UploadedGoalExampleOut.model_validate(
            row_with(example, warnings=_warnings(image.original, example.id, frame, goal_set, settings, set_photos)),
            from_attributes=True,
        )
        for example, image in zip(stored, prepared, strict=True)
    ]


@router.get(
    "/api/goal-examples/{example_id}/image",
    response_class=Response,
    responses={200: {"content": {"image/png": {}, "image/jpeg": {}, "image/webp": {}}}, **errors(403, 404)},
)
def goal_example_image(
    example_id: GoalExampleId,
    store: StoreDep,
    _auth: ReadAuth,
    _same_site: SameSiteRead,
    kind: Annotated[Literal["original", "model", "display"], Query()] = "display",
) -> Response:
    """original: the upload as sent; model: what the classifier sees; display: the whole photo, max 256 px."""
    media_type = "image/png"
    if kind == "original":
        media_type = store.get_goal_example(example_id=example_id).original_media_type
    data = store.goal_example_image(example_id=example_id, kind=kind)
    return Response(content=data, media_type=media_type, headers=IMAGE_CACHE)


@router.delete(
    "/api/goal-examples/{example_id}", status_code=status.HTTP_204_NO_CONTENT, responses=errors(404, *WRITE_ERRORS)
)
def delete_goal_example(example_id: GoalExampleId, store: StoreDep, _auth: WriteAuth) -> Response:
    store.delete_goal_example(example_id=example_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


# ---------------------------------------------------------------- goals from the robot's camera
CAMERA_ERRORS: dict[int | str, dict[str, Any]] = {
    409: {
        "model": ErrorOut,
        "description": "No robot process publishes the camera's frames (how to start one), or "
        "it has published none yet",
    }
}
NO_STORE = {"Cache-Control": "no-store"}
CameraEnvId = Annotated[
    str, Query(min_length=1, max_length=200, description="A robot env with a camera (one of GET /api/cameras).")
]


def frame_url(env_id: str) -> str:
    return "/api/cameras/frame?" + urlencode({"env_id": env_id})


def is_camera_env(env_id: str | None, settings: Settings) -> bool:
    """Whether env_id is one of GET /api/cameras. An allowed id whose class has no camera is answered from the
    registry at once; the rest from the list (found once a process)."""
    if not env_id:
        return False
    module = env_id.split(":", 1)[0] if ":" in env_id else None
    if module is None and env_id not in SIM_ENV_IDS:
        return False
    if module is not None and not module_allowed(module, settings.env_modules):
        return False
    try:
        if robot_class(env_id) is False:
            return False
    except Exception:  # noqa: BLE001 - an id whose module does not import has no camera
        return False
    return env_id in camera_env_ids(settings.env_modules)


def _not_a_camera(env_id: str, loc: list[str], settings: Settings) -> HTTPException:
    listed = ", ".join(camera_env_ids(settings.env_modules)) or "none"
    message = f"{env_id!r} is not a robot env with a camera here (GET /api/cameras lists: {listed})"
    return HTTPException(status_code=422, detail=[{"loc": loc, "msg": message, "type": "value_error"}])


def _camera_frame(env_id: str, store: Store) -> CameraFrame:
    try:
        return cameras.frame(env_id, store)
    except CameraUnavailable as error:  # (the robot's state, not this server's: its process is not up)
        raise HTTPException(status_code=409, detail=str(error)) from None


def _set_camera_frame(goal_set: GoalSet, settings: Settings, store: Store) -> CameraFrame | None:
    """The current frame of the set's robot camera, or None when its task has none or it cannot be read."""
    if not is_camera_env(goal_set.env_id, settings):
        return None
    try:
        return cameras.frame(goal_set.env_id or "", store)
    except CameraUnavailable:
        return None


def _set_photos(store: Store, goal_set_id: int) -> dict[int, Image.Image]:
    """The model's view of each photo of the set, by example id."""
    return {
        example.id: Image.open(io.BytesIO(store.goal_example_image(example_id=example.id, kind="model")))
        for example in store.list_goal_examples(goal_set_id=goal_set_id)
    }


def _differences(
    image: Image.Image, frame: CameraFrame | None, goal_set: GoalSet, set_photos: list[Image.Image]
) -> list[PhotoWarningOut]:
    """How a photo differs from the camera's frame (when there is one) and from the viewpoint of the set's photos."""
    found: list[PhotoDifference] = [] if frame is None else photo_differences(image, frame.pixels, goal_set.image_size)
    viewpoint = viewpoint_difference(image, set_photos)
    if viewpoint is not None:
        found.append(viewpoint)
    return [PhotoWarningOut(kind=item.kind, message=item.message) for item in found]


def _warnings(
    photo: bytes, example_id: int, frame: CameraFrame | None, goal_set: GoalSet, settings: Settings,
    set_photos: dict[int, Image.Image],
) -> list[PhotoWarningOut]:  # fmt: skip
    image = decode_upload(photo, max_bytes=max(len(photo), 1), max_pixels=settings.max_image_pixels)
    others = [other for other_id, other in set_photos.items() if other_id != example_id]
    return _differences(image, frame, goal_set, others)


@router.get("/api/cameras", response_model=CamerasOut, tags=["cameras"])
def list_cameras(settings: SettingsDep, store: StoreDep, _auth: ReadAuth) -> CamerasOut:
    """The robot envs with a camera: the stand-in robot's and the allowed modules' (RAQ_ENV_MODULES) envs whose
    class is a robot.base.RobotEnv with read_camera (told from the registry, without making the env), each with the
    robot's own process when one is up (only that process opens the camera)."""
    listed = []
    for env_id in camera_env_ids(settings.env_modules):
        process = store.robot_process_of(env_id=env_id)
        listed.append(CameraOut(
            env_id=env_id, frame_url=frame_url(env_id), robot=None if process is None else process.robot,
            robot_state=None if process is None else process.state,
        ))  # fmt: skip
    return CamerasOut(cameras=listed)


@router.get(
    "/api/cameras/frame",
    response_class=Response,
    tags=["cameras"],
    responses={
        200: {"content": {"image/png": {}}, "description": "The camera's whole frame, as the robot sees it."},
        **CAMERA_ERRORS,
        **errors(403),
    },
)
def camera_frame(
    env_id: CameraEnvId, settings: SettingsDep, store: StoreDep, _auth: ReadAuth, _same_site: SameSiteRead
) -> Response:
    """The robot camera's current frame (read without resetting the env, at most every 0.2 s; the frame a run's
    live actor on the same env published, when one is). X-Camera-Source: 'camera' or 'run N'."""
    if not is_camera_env(env_id, settings):
        raise _not_a_camera(env_id, ["query", "env_id"], settings)
    frame = _camera_frame(env_id, store)
    return Response(content=frame.png, media_type="image/png", headers={**NO_STORE, "X-Camera-Source": frame.source})


@router.post(
    "/api/goal-sets/{goal_set_id}/capture",
    status_code=status.HTTP_201_CREATED,
    response_model=GoalExampleOut,
    tags=["cameras"],
    responses={**errors(404, *WRITE_ERRORS), **CAMERA_ERRORS},
)
def capture_goal_example(
    goal_set_id: GoalSetId, body: CaptureCreate, store: StoreDep, settings: SettingsDep, _auth: WriteAuth
) -> GoalExampleOut:
    """The robot camera's current frame becomes a goal photo (source "camera"): the whole frame is its original,
    and its model and display copies are made as an upload's are."""
    goal_set = store.get_goal_set(goal_set_id=goal_set_id)
    if not is_camera_env(body.env_id, settings):
        raise _not_a_camera(body.env_id, ["body", "env_id"], settings)
    frame = _camera_frame(body.env_id, store)
    moment = datetime.now(UTC).strftime("%Y%m%d-%H%M%S-%f")[:-3]
    image = prepare_upload(
        frame.png, filename=f"camera-{moment}.png", model_size=goal_set.image_size,
        max_bytes=max(len(frame.png), settings.max_upload_bytes),
        max_pixels=max(frame.width * frame.height, settings.max_image_pixels),
    )  # fmt: skip
    example = store.add_goal_example(
        goal_set_id=goal_set_id, filename=image.filename, original=image.original,
        original_media_type=image.media_type, width=image.width, height=image.height, model_png=image.model_png,
        display_png=image.display_png, source="camera",
    )  # fmt: skip
    return GoalExampleOut.model_validate(example, from_attributes=True)


@router.post(
    "/api/goal-sets/{goal_set_id}/photo-check",
    response_model=PhotoCheckOut,
    tags=["cameras"],
    responses={
        **errors(404, *WRITE_ERRORS),
        **CAMERA_ERRORS,
        400: {"model": ErrorOut, "description": "The file is not a usable image"},
    },
)
def check_goal_photo(
    goal_set_id: GoalSetId,
    file: Annotated[UploadFile, File(description="One PNG, JPEG or WebP photo, as it would be uploaded.")],
    store: StoreDep,
    settings: SettingsDep,
    _auth: WriteAuth,
    env_id: Annotated[
        str | None,
        Query(max_length=200, description="The robot camera to compare with; default: the set's task's."),
    ] = None,
) -> PhotoCheckOut:
    """How a photo differs from the robot camera's current frame (shape, size, colours, contrast) and from the
    viewpoint of the set's photos, before it is uploaded. Stores nothing. No camera (and only the viewpoint
    warning) when the set's task is not a robot env with a camera."""
    goal_set = store.get_goal_set(goal_set_id=goal_set_id)
    filename = _clean_filename(file.filename, 0)
    data = file.file.read(settings.max_upload_bytes + 1)
    try:
        image = decode_upload(data, max_bytes=settings.max_upload_bytes, max_pixels=settings.max_image_pixels)
    except ImageRejected as error:
        raise HTTPException(status_code=error.status_code, detail=f"{filename}: {error.message}") from None
    photo = PhotoInfo(filename=filename, width=image.width, height=image.height)
    if env_id is not None and not is_camera_env(env_id, settings):
        raise _not_a_camera(env_id, ["query", "env_id"], settings)
    chosen = env_id or (goal_set.env_id if is_camera_env(goal_set.env_id, settings) else None)
    set_photos = list(_set_photos(store, goal_set_id).values())
    if chosen is None:
        return PhotoCheckOut(warnings=_differences(image, None, goal_set, set_photos), camera=None, photo=photo)
    frame = _camera_frame(chosen, store)
    return PhotoCheckOut(
        warnings=_differences(image, frame, goal_set, set_photos),
        camera=CameraFrameInfo(
            env_id=chosen, source=frame.source, width=frame.width, height=frame.height, frame_url=frame_url(chosen)
        ),
        photo=photo,
    )
