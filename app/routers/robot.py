"""A run's robot: what a person does for the actor that drives it in real time (Stop robot, Resume, Ready once
the scene is reset, Evaluate now, a take-over by hand) and the actor's newest camera frame; GET /api/robots lists
the robots at work, for the pages."""

from fastapi import APIRouter, HTTPException, Response

from app.deps import ReadAuth, RunId, SameSiteRead, StoreDep, WriteAuth
from app.schemas import WRITE_ERRORS, DemosIn, DriveIn, EvaluateIn, RobotStatusOut, errors
from app.views import robot_status_out
from contract.store import NotFound, RobotStatus, Store

run_robot = APIRouter(prefix="/api/runs", tags=["robot"], responses=errors(401))
robots = APIRouter(prefix="/api/robots", tags=["robot"], responses=errors(401))
router = APIRouter()
"""Both, as the app includes them."""

NO_STORE = {"Cache-Control": "no-store"}


def robot_out(store: Store, status: RobotStatus, *, judged: bool = True) -> RobotStatusOut:
    return robot_status_out(status, store.get_run(run_id=status.run_id), store, judged=judged)


@run_robot.get("/{run_id}/robot", response_model=RobotStatusOut, responses=errors(404))
def robot_status(run_id: RunId, store: StoreDep, _auth: ReadAuth) -> RobotStatusOut:
    """The run's robot controls and what its actor last said (`live`: it reported within ROBOT_LIVE_SECONDS)."""
    return robot_out(store, store.robot_status(run_id=run_id))


@run_robot.post("/{run_id}/robot/stop", response_model=RobotStatusOut, responses=errors(404, *WRITE_ERRORS))
def stop_robot(run_id: RunId, store: StoreDep, _auth: WriteAuth) -> RobotStatusOut:
    """Stop robot: the actor holds the arm still from its next report (one control period) until Resume. Pressing
    it again changes nothing."""
    return robot_out(store, store.request_robot_stop(run_id=run_id))


@run_robot.post("/{run_id}/robot/resume", response_model=RobotStatusOut, responses=errors(404, *WRITE_ERRORS))
def resume_robot(run_id: RunId, store: StoreDep, _auth: WriteAuth) -> RobotStatusOut:
    """Resume after Stop robot: the actor may move the arm again. Without a stop it changes nothing."""
    return robot_out(store, store.resume_robot(run_id=run_id))


@run_robot.post("/{run_id}/robot/ready", response_model=RobotStatusOut, responses=errors(404, 409, *WRITE_ERRORS))
def scene_ready(run_id: RunId, store: StoreDep, _auth: WriteAuth) -> RobotStatusOut:
    """Ready: the scene is reset and the actor may start its episode (409 when no reset is waiting)."""
    return robot_out(store, store.scene_ready(run_id=run_id))


@run_robot.post(
    "/{run_id}/robot/evaluate",
    response_model=RobotStatusOut,
    status_code=202,
    responses=errors(404, 409, *WRITE_ERRORS),
)
def evaluate_now(run_id: RunId, body: EvaluateIn, store: StoreDep, _auth: WriteAuth) -> RobotStatusOut:
    """Evaluate now: the actor runs the next `episodes` episodes with the policy's mean action; the last frame of
    each becomes a question, and the share of yes answers is the round's eval/success_rate (409 while an earlier
    request still has episodes pending)."""
    return robot_out(store, store.request_evaluation(run_id=run_id, episodes=body.episodes))


@run_robot.post(
    "/{run_id}/robot/drive", response_model=RobotStatusOut, status_code=202, responses=errors(404, 409, *WRITE_ERRORS)
)
def drive_robot(run_id: RunId, body: DriveIn, store: StoreDep, _auth: WriteAuth) -> RobotStatusOut:
    """Take over: the person's action, sent instead of the policy's by the robot's own process (same pace, action
    limits, hold and Stop) for one control period from when it sees it. The page sends one every half period while
    a key is held; once they stop coming the policy drives again. 409 while Stop robot is pending or before the
    robot's actor has announced its action space; 422 for an action outside [-1, 1], 400 for one of the wrong length."""
    return robot_out(store, store.drive_robot(run_id=run_id, action=body.action), judged=False)


@run_robot.post("/{run_id}/robot/hand-back", response_model=RobotStatusOut, responses=errors(404, *WRITE_ERRORS))
def hand_back_robot(run_id: RunId, store: StoreDep, _auth: WriteAuth) -> RobotStatusOut:
    """End a take-over: the policy drives again from the actor's next step."""
    return robot_out(store, store.hand_back_robot(run_id=run_id), judged=False)


@run_robot.post(
    "/{run_id}/robot/success", response_model=RobotStatusOut, status_code=202, responses=errors(404, 409, *WRITE_ERRORS)
)
def mark_success(run_id: RunId, store: StoreDep, _auth: WriteAuth) -> RobotStatusOut:
    """The success key (G): the episode under way, or the one that just ended, is a success; its last frames join
    the classifier's positives. It also ends a demo episode. 409 before the robot's actor has reported."""
    return robot_out(store, store.mark_success(run_id=run_id))


@run_robot.post(
    "/{run_id}/robot/demos", response_model=RobotStatusOut, status_code=202, responses=errors(404, 409, *WRITE_ERRORS)
)
def record_demos(run_id: RunId, body: DemosIn, store: StoreDep, _auth: WriteAuth) -> RobotStatusOut:
    """Record demos: the robot's next `episodes` episodes are driven by hand; in each the arm moves only while the
    person holds a drive key (the policy idle), and the success key ends it. 409 while earlier demos are pending or
    before the robot's actor has reported."""
    return robot_out(store, store.request_demos(run_id=run_id, episodes=body.episodes))


@run_robot.get(
    "/{run_id}/robot/camera",
    response_class=Response,
    responses={
        200: {"content": {"image/png": {}}, "description": "The actor's newest camera frame."},
        **errors(403, 404),
    },
)
def robot_camera(run_id: RunId, store: StoreDep, _auth: ReadAuth, _same_site: SameSiteRead) -> Response:
    """The actor's newest camera frame (PNG, never cached: each request gets the newest); 404 before the first."""
    frame = store.camera_frame(run_id=run_id)
    if frame is None:
        raise HTTPException(status_code=404, detail=f"run {run_id} has no camera frame yet", headers=NO_STORE)
    data, frame_at = frame
    return Response(content=data, media_type="image/png", headers={**NO_STORE, "X-Frame-At": frame_at.isoformat()})


@robots.get("", response_model=list[RobotStatusOut])
def robots_at_work(store: StoreDep, _auth: ReadAuth) -> list[RobotStatusOut]:
    """The active runs whose actor reported within the last 30 s, by run id: the queue page's reset cards and Stop
    robot buttons."""
    listed = []
    for status in store.robot_runs():
        try:
            listed.append(robot_out(store, status))
        except NotFound:  # deleted meanwhile
            continue
    return listed


router.include_router(run_robot)
router.include_router(robots)
