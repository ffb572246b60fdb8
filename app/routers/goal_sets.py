"""Goal sets and their goal photos: create, upload (one or several at once), list, images, delete."""

from pathlib import PurePosixPath, PureWindowsPath
from typing import Annotated, Literal

from fastapi import APIRouter, File, HTTPException, Query, Response, UploadFile, status

from app.deps import GoalExampleId, GoalSetId, ReadAuth, SettingsDep, StoreDep, WriteAuth
from app.schemas import (
    WRITE_ERRORS,
    ErrorOut,
    GoalExampleOut,
    GoalSetCreate,
    GoalSetDetail,
    GoalSetOut,
    errors,
    row_with,
)
from contract.images import ImageRejected, PreparedImage, prepare_upload

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
    response_model=list[GoalExampleOut],
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
) -> list[GoalExampleOut]:
    """Every file is checked before any is stored: one bad file rejects the whole upload."""
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
    return [GoalExampleOut.model_validate(example, from_attributes=True) for example in stored]


@router.get(
    "/api/goal-examples/{example_id}/image",
    response_class=Response,
    responses={200: {"content": {"image/png": {}, "image/jpeg": {}, "image/webp": {}}}, **errors(404)},
)
def goal_example_image(
    example_id: GoalExampleId,
    store: StoreDep,
    _auth: ReadAuth,
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
