"""A run's exports: metrics as CSV or TensorBoard event files, the queries with their answers and images (zip), the
trained policy (the learner's policy file, streamed as it is: no torch here) and the evaluation rollout as a video."""

import io
import zipfile
from pathlib import Path
from typing import Annotated, Literal

from fastapi import APIRouter, Depends, HTTPException, Query, Response
from fastapi.responses import FileResponse, StreamingResponse

from app.deps import QueryBool, ReadAuth, RunId, SettingsDep, StoreDep, require_same_site_read
from app.exports import gif_to_avi, metrics_csv, queries_zip, tensorboard_events
from app.schemas import EvaluatedPoliciesOut, errors
from app.views import EVALUATED_POLICY_FILES, POLICY_FILES, evaluated_policies
from contract.checkpoint_location import (
    is_remote,
    run_folder,
)

# every export is refused to another site's page (Sec-Fetch-Site: cross-site): each one reads the whole run
router = APIRouter(
    prefix="/api/runs", tags=["exports"], dependencies=[Depends(require_same_site_read)],
    responses=errors(401, 403, 404),
)  # fmt: skip


def _attachment(name: str) -> dict[str, str]:
    return {"Content-Disposition": f'attachment; filename="{name}"', "Cache-Control": "no-cache"}


@router.get(
    "/{run_id}/metrics.csv",
    response_class=StreamingResponse,
    responses={200: {"content": {"text/csv": {}}, "description": "step, then one column per metric name."}},
)
def metrics_as_csv(run_id: RunId, store: StoreDep, _auth: ReadAuth) -> StreamingResponse:
    store.get_run(run_id=run_id)
    return StreamingResponse(
        metrics_csv(store, run_id=run_id), media_type="text/csv", headers=_attachment(f"run-{run_id}-metrics.csv")
    )


@router.get(
    "/{run_id}/tensorboard.zip",
    response_class=Response,
    responses={200: {"content": {"application/zip": {}}, "description": "run-<id>/events.out.tfevents.*"}},
)
def metrics_as_tensorboard(run_id: RunId, store: StoreDep, _auth: ReadAuth) -> Response:
    """The metrics as a TensorBoard event file: unzip, then `tensorboard --logdir .`."""
    store.get_run(run_id=run_id)
    rows = ((m.step, m.name, m.value, m.created_at.timestamp()) for m in store.metrics(run_id=run_id))
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        archive.writestr(f"run-{run_id}/events.out.tfevents.0.vice-raq", tensorboard_events(rows))
    return Response(buffer.getvalue(), media_type="application/zip", headers=_attachment(f"run-{run_id}-tb.zip"))


@router.get(
    "/{run_id}/queries.zip",
    response_class=Response,
    responses={200: {"content": {"application/zip": {}}, "description": "queries.csv and images/*.png"}},
)
def queries_as_zip(run_id: RunId, store: StoreDep, _auth: ReadAuth) -> Response:
    store.get_run(run_id=run_id)
    return Response(
        queries_zip(store, run_id=run_id),
        media_type="application/zip",
        headers=_attachment(f"run-{run_id}-queries.zip"),
    )


@router.get(
    "/{run_id}/policy",
    response_class=FileResponse,
    responses={200: {"content": {"application/octet-stream": {}}, "description": "Load with learner.policy."}},
)
def policy(
    run_id: RunId,
    store: StoreDep,
    settings: SettingsDep,
    _auth: ReadAuth,
    which: Annotated[
        Literal["checkpoint", "last_eval", "best"],
        Query(
            description="checkpoint: as of the last checkpoint; last_eval: the policy the latest evaluation ran; "
            "best: the one of the highest evaluation success rate (GET …/policies gives their steps and scores)"
        ),
    ] = "checkpoint",
) -> FileResponse:
    """The trained policy: `learner.policy.load_policy(path).act(image)`."""
    store.get_run(run_id=run_id)
    folder = run_folder(settings.resolved_checkpoint_url, run_id)
    if which != "checkpoint":
        response = _run_file(folder, run_id, EVALUATED_POLICY_FILES[which])
        if response is None:
            raise HTTPException(status_code=404, detail=f"run {run_id} has no evaluated policy yet")
        return response
    for name in POLICY_FILES:
        response = _run_file(folder, run_id, name)
        if response is not None:
            return response
    raise HTTPException(
        status_code=404, detail=f"run {run_id} has no checkpoint yet (written every checkpoint_every steps)"
    )


@router.get("/{run_id}/policies", response_model=EvaluatedPoliciesOut)
def policies(run_id: RunId, store: StoreDep, settings: SettingsDep, _auth: ReadAuth) -> EvaluatedPoliciesOut:
    """The policies the evaluations judged: the latest one's and the best one's, each with its step and score."""
    store.get_run(run_id=run_id)
    return evaluated_policies(settings, run_id)


def _run_file(folder: str, run_id: int, name: str) -> FileResponse | StreamingResponse | None:
    """The run's file `name` as a download, or None when there is none."""
    if not is_remote(folder):
        path = Path(folder) / name
        if path.is_file():
            return FileResponse(path, media_type="application/octet-stream", filename=f"run-{run_id}-{name}")
        return None
    import fsspec  # checkpoints in object storage (pip install '.[objectstore]')

    fs, key = fsspec.core.url_to_fs(f"{folder}/{name}")
    if fs.isfile(key):
        return StreamingResponse(
            fs.open(key, "rb"), media_type="application/octet-stream", headers=_attachment(f"run-{run_id}-{name}")
        )
    return None


@router.get(
    "/{run_id}/rollout.avi",
    response_class=Response,
    responses={200: {"content": {"video/x-msvideo": {}}, "description": "Motion-JPEG AVI of the latest rollout."}},
)
def rollout_video(
    run_id: RunId,
    store: StoreDep,
    _auth: ReadAuth,
    download: Annotated[QueryBool, Query(description="as an attachment")] = True,
) -> Response:
    store.get_run(run_id=run_id)
    rollout = store.latest_rollout(run_id=run_id)
    if rollout is None:
        raise HTTPException(status_code=404, detail=f"run {run_id} has no rollout yet")
    try:
        video = gif_to_avi(store.rollout_data(rollout_id=rollout.id))
    except (OSError, ValueError, SyntaxError):  # not a readable animation (Pillow's errors for broken images)
        raise HTTPException(status_code=404, detail=f"run {run_id}: its latest rollout is not a readable GIF") from None
    headers = _attachment(f"run-{run_id}-step-{rollout.env_step}.avi") if download else {}
    return Response(video, media_type="video/x-msvideo", headers=headers)
