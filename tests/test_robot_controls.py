"""A run's robot controls: a person's Stop robot / Resume, Ready and Evaluate now, the actor's call for a scene
reset, its reports and camera frames, in the store (a real SQLite file) and through the REST API."""

import io
import threading
from collections.abc import Callable
from datetime import timedelta

import pytest
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from fastapi.testclient import TestClient
from PIL import Image
from sqlalchemy import select, update

from contract.config import TrainConfig
from contract.store import Conflict, InvalidInput, NotFound, RobotStatus, RunStatus, Store
from contract.store.models import Base, RobotControl, utcnow
from contract.store.robots import EVALUATION_EPISODES_MAX


def _png(color: tuple[int, int, int] = (40, 70, 200)) -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (32, 24), color).save(buffer, format="PNG")
    return buffer.getvalue()


def _run(store: Store, *, active: bool = False) -> int:
    run_id = store.create_run(env_id="VisualPusher-v0", algorithm="vice_raq", config={}, total_steps=1000).id
    if active:
        assert store.claim_next_run(worker="robot-learner").id == run_id
        store.heartbeat(run_id=run_id, worker="robot-learner", status=RunStatus.TRAINING)
    return run_id


def _rows(store: Store) -> list[tuple]:
    with store.reading() as session:
        return [tuple(row) for row in session.execute(select(*RobotControl.__table__.columns)).all()]


# ---------------------------------------------------------------- store
def test_a_run_nobody_touched_has_the_defaults_and_no_row(store: Store) -> None:
    run_id = _run(store)
    assert store.robot_status(run_id=run_id) == RobotStatus(
        run_id=run_id, stop_requested=False, reset_needed=False, reset_count=0, actor_state=None,
        actor_seen_at=None, frame_at=None, evaluation_pending=0, evaluation_round=0, takeover_action=None,
        takeover_seq=0, actor_spaces=None, success_marks=0, demo_pending=0,
    )  # fmt: skip
    assert store.hand_back_robot(run_id=run_id).takeover_action is None  # nothing to hand back: nothing made
    assert store.camera_frame(run_id=run_id) is None
    assert store.take_evaluation_episode(run_id=run_id) is None  # nothing asked: nothing taken, nothing made
    assert store.resume_robot(run_id=run_id).stop_requested is False  # nothing to resume: nothing made
    assert _rows(store) == []


def test_stop_and_resume_are_idempotent_and_leave_one_event_each(store: Store) -> None:
    run_id = _run(store)
    assert store.request_robot_stop(run_id=run_id).stop_requested is True
    assert store.request_robot_stop(run_id=run_id).stop_requested is True
    assert store.robot_status(run_id=run_id).stop_requested is True
    assert store.resume_robot(run_id=run_id).stop_requested is False
    assert store.resume_robot(run_id=run_id).stop_requested is False
    messages = [event.message for event in store.events(run_id=run_id)]
    assert messages.count("robot stop requested: the arm holds still") == 1
    assert messages.count("robot resumed") == 1
    assert len(_rows(store)) == 1


def test_ready_needs_a_waiting_reset_and_counts_each(store: Store) -> None:
    run_id = _run(store)
    with pytest.raises(Conflict, match="no reset is waiting"):
        store.scene_ready(run_id=run_id)
    assert _rows(store) == []  # refused: nothing made
    for count in (1, 2):
        waiting = store.request_scene_reset(run_id=run_id)
        assert waiting.reset_needed is True and waiting.reset_count == count - 1
        assert store.request_scene_reset(run_id=run_id) == waiting  # asked twice: still one reset
        ready = store.scene_ready(run_id=run_id)
        assert ready.reset_needed is False and ready.reset_count == count
        before = _rows(store)
        with pytest.raises(Conflict, match="no reset is waiting"):
            store.scene_ready(run_id=run_id)  # pressed twice: counted once
        assert _rows(store) == before


def _run_with_actor(store: Store) -> int:
    """A run whose actor has reported (it drives the robot in real time)."""
    run_id = _run(store)
    store.report_actor(run_id=run_id, state="acting")
    return run_id


def test_evaluate_now_is_refused_before_an_actor_drives_the_run(store: Store) -> None:
    run_id = _run(store)
    events = len(store.events(run_id=run_id))
    with pytest.raises(Conflict, match="no actor drives this run's robot"):
        store.request_evaluation(run_id=run_id, episodes=2)
    assert _rows(store) == [] and len(store.events(run_id=run_id)) == events
    store.request_robot_stop(run_id=run_id)  # a person's row, still no actor
    before = _rows(store)
    with pytest.raises(Conflict, match="no actor drives this run's robot"):
        store.request_evaluation(run_id=run_id, episodes=2)
    assert _rows(store) == before


def test_evaluate_now_asks_for_episodes_that_the_actor_takes_one_by_one(store: Store) -> None:
    run_id = _run_with_actor(store)
    asked = store.request_evaluation(run_id=run_id, episodes=2)
    assert (asked.evaluation_pending, asked.evaluation_round) == (2, 1)
    assert store.robot_status(run_id=run_id) == asked
    before = _rows(store)
    with pytest.raises(Conflict, match="2 episodes of round 1 not begun yet"):
        store.request_evaluation(run_id=run_id, episodes=5)  # pressed again while pending: nothing changes
    assert _rows(store) == before
    assert store.report_actor(run_id=run_id, state="moving").evaluation_pending == 2  # the actor reads it
    assert [store.take_evaluation_episode(run_id=run_id) for _ in range(3)] == [1, 1, None]
    assert store.robot_status(run_id=run_id).evaluation_pending == 0
    again = store.request_evaluation(run_id=run_id, episodes=EVALUATION_EPISODES_MAX)  # the round is over
    assert (again.evaluation_pending, again.evaluation_round) == (EVALUATION_EPISODES_MAX, 2)
    assert store.take_evaluation_episode(run_id=run_id) == 2
    messages = [event.message for event in store.events(run_id=run_id)]
    assert "evaluate now: round 1, 2 episodes with the policy's mean action" in messages
    assert f"evaluate now: round 2, {EVALUATION_EPISODES_MAX} episodes with the policy's mean action" in messages


def test_two_actors_taking_the_last_episode_at_once_take_it_once(store: Store) -> None:
    run_id = _run_with_actor(store)
    store.request_evaluation(run_id=run_id, episodes=3)
    taken: list[int | None] = []
    barrier = threading.Barrier(6)

    def take() -> None:
        barrier.wait()
        taken.append(store.take_evaluation_episode(run_id=run_id))

    threads = [threading.Thread(target=take) for _ in range(6)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert sorted(taken, key=lambda value: value is None) == [1, 1, 1, None, None, None]
    assert store.robot_status(run_id=run_id).evaluation_pending == 0


@pytest.mark.parametrize("episodes", [0, -1, EVALUATION_EPISODES_MAX + 1, True, 2.5, "3"])
def test_evaluate_now_refuses_a_bad_count_and_changes_nothing(store: Store, episodes: object) -> None:
    run_id = _run_with_actor(store)
    before = _rows(store)
    with pytest.raises(InvalidInput, match=f"from 1 to {EVALUATION_EPISODES_MAX}"):
        store.request_evaluation(run_id=run_id, episodes=episodes)  # type: ignore[arg-type]
    assert _rows(store) == before
    store.request_evaluation(run_id=run_id, episodes=1)
    store.take_evaluation_episode(run_id=run_id)
    before = _rows(store)
    with pytest.raises(InvalidInput):
        store.request_evaluation(run_id=run_id, episodes=episodes)  # type: ignore[arg-type]
    assert _rows(store) == before
    assert [event.message for event in store.events(run_id=run_id)].count(
        "evaluate now: round 1, 1 episode with the policy's mean action"
    ) == 1


def test_report_actor_stamps_the_time_keeps_the_frame_and_returns_the_controls(store: Store) -> None:
    run_id = _run(store)
    first = store.report_actor(run_id=run_id, state="waiting for a reset")
    assert first.actor_state == "waiting for a reset" and first.actor_seen_at is not None and first.frame_at is None
    assert abs((first.actor_seen_at - utcnow()).total_seconds()) < 5
    assert store.camera_frame(run_id=run_id) is None
    store.request_robot_stop(run_id=run_id)
    store.request_scene_reset(run_id=run_id)
    frame = _png()
    reported = store.report_actor(run_id=run_id, state="holding still", frame_png=frame)
    assert reported.stop_requested is True and reported.reset_needed is True  # the controls, same round trip
    assert reported.frame_at is not None and reported.actor_seen_at >= first.actor_seen_at
    assert store.camera_frame(run_id=run_id) == (frame, reported.frame_at)
    # a report without a frame keeps the newest frame and when it came
    later = store.report_actor(run_id=run_id, state="x" * 300)
    assert later.actor_state == "x" * 100 and later.frame_at == reported.frame_at
    assert store.camera_frame(run_id=run_id) == (frame, reported.frame_at)
    newer = _png((200, 40, 40))
    assert store.camera_frame(run_id=run_id) != newer
    store.report_actor(run_id=run_id, state="moving", frame_png=newer)
    assert store.camera_frame(run_id=run_id)[0] == newer


@pytest.mark.parametrize(
    ("state", "frame", "message"),
    [
        ("moving", b"GIF89a not a png", "must be a PNG image"),
        ("moving", b"", "must be a PNG image"),
        ("moving", "a text", "must be PNG bytes"),
        ("bad\x00state", None, "without NUL"),
        (7, None, "must be text"),
    ],
)
def test_a_bad_report_is_refused_and_stores_nothing(store: Store, state: object, frame: object, message: str) -> None:
    run_id = _run(store)
    store.report_actor(run_id=run_id, state="moving", frame_png=_png())
    before = _rows(store)
    with pytest.raises(InvalidInput, match=message):
        store.report_actor(run_id=run_id, state=state, frame_png=frame)  # type: ignore[arg-type]
    assert _rows(store) == before


def test_an_unknown_run_is_not_found_everywhere(store: Store) -> None:
    calls = [
        store.robot_status, store.request_robot_stop, store.resume_robot, store.request_scene_reset,
        store.scene_ready, store.camera_frame,
    ]  # fmt: skip
    for call in calls:
        with pytest.raises(NotFound, match="run 404 not found"):
            call(run_id=404)
    with pytest.raises(NotFound, match="run 404 not found"):
        store.request_evaluation(run_id=404, episodes=2)
    assert store.take_evaluation_episode(run_id=404) is None
    with pytest.raises(NotFound, match="run 404 not found"):
        store.report_actor(run_id=404, state="moving", frame_png=_png())
    assert _rows(store) == []


def test_robot_runs_lists_active_runs_whose_actor_reported_recently(store: Store) -> None:
    stale, live = _run(store, active=True), _run(store, active=True)
    queued = _run(store)  # (after them: a learner would take it first)
    assert store.robot_runs() == []
    store.request_robot_stop(run_id=live)  # controls alone: no actor seen yet
    assert store.robot_runs() == []
    for run_id in (queued, stale, live):
        store.report_actor(run_id=run_id, state="moving")
    assert [status.run_id for status in store.robot_runs()] == [stale, live]
    with store.writing() as session:  # the stale one's actor last reported a minute ago
        session.execute(
            update(RobotControl)
            .where(RobotControl.run_id == stale)
            .values(actor_seen_at=utcnow() - timedelta(seconds=60))
        )
    [status] = store.robot_runs()
    assert status.run_id == live and status.stop_requested is True and status.actor_state == "moving"
    store.set_run_status(run_id=live, status=RunStatus.STOPPED)
    assert store.robot_runs() == []


def test_deleting_a_run_deletes_its_controls(store: Store) -> None:
    run_id = _run(store)
    store.report_actor(run_id=run_id, state="moving", frame_png=_png())
    store.request_stop(run_id=run_id)  # queued: stopped at once
    store.delete_run(run_id=run_id)
    assert _rows(store) == []


def test_the_migrations_make_the_robot_controls_table_the_model_describes(store: Store) -> None:
    with store.engine.connect() as connection:
        context = MigrationContext.configure(connection, opts={"compare_type": True, "compare_server_default": True})
        differences = [diff for diff in compare_metadata(context, Base.metadata) if "robot_controls" in repr(diff)]
    assert differences == []


def _age_actor(store: Store, run_id: int, seconds: float) -> None:
    """As if the run's actor last reported `seconds` ago."""
    with store.writing() as session:
        session.execute(
            update(RobotControl)
            .where(RobotControl.run_id == run_id)
            .values(actor_seen_at=utcnow() - timedelta(seconds=seconds))
        )


# ---------------------------------------------------------------- REST API
def test_the_api_stops_resumes_and_says_whether_the_actor_is_live(client: TestClient, store: Store) -> None:
    run_id = _run(store)
    shown = client.get(f"/api/runs/{run_id}/robot").json()
    assert shown == {
        "run_id": run_id, "run_name": "", "stop_requested": False, "reset_needed": False, "reset_count": 0,
        "actor_state": None, "actor_seen_at": None, "actor_age_seconds": None, "live": False, "frame_at": None,
        "camera_url": None, "evaluation_pending": 0, "evaluation_round": 0, "takeover_action": None,
        "action_dims": None, "control_hz": None, "asks_for_help": False, "success_marks": 0, "demo_pending": 0,
    }  # fmt: skip
    for _ in range(2):
        stopped = client.post(f"/api/runs/{run_id}/robot/stop")
        assert stopped.status_code == 200 and stopped.json()["stop_requested"] is True
    assert store.robot_status(run_id=run_id).stop_requested is True
    for _ in range(2):
        resumed = client.post(f"/api/runs/{run_id}/robot/resume")
        assert resumed.status_code == 200 and resumed.json()["stop_requested"] is False
    store.report_actor(run_id=run_id, state="moving")
    live = client.get(f"/api/runs/{run_id}/robot").json()
    assert live["live"] is True and live["actor_state"] == "moving" and 0 <= live["actor_age_seconds"] < 5
    _age_actor(store, run_id, 6)
    assert client.get(f"/api/runs/{run_id}/robot").json()["live"] is False


def test_the_runs_own_answer_shows_its_actor_silent_within_the_watchdog_time(client: TestClient, store: Store) -> None:
    """GET /api/runs/{id} carries the robot's card once an actor reported: live while it reports, not live once it
    has been silent longer than the actor's watchdog time (a paused or cut-off robot process)."""
    run_id = _run(store)
    assert client.get(f"/api/runs/{run_id}").json()["robot"] is None
    store.report_actor(run_id=run_id, state="acting")
    robot = client.get(f"/api/runs/{run_id}").json()["robot"]
    assert robot["live"] is True and robot["actor_state"] == "acting"
    _age_actor(store, run_id, TrainConfig().watchdog_seconds + 0.1)
    assert client.get(f"/api/runs/{run_id}").json()["robot"]["live"] is False


def test_ready_is_409_without_a_waiting_reset_and_counts_after_one(client: TestClient, store: Store) -> None:
    run_id = _run(store)
    refused = client.post(f"/api/runs/{run_id}/robot/ready")
    assert refused.status_code == 409 and refused.json() == {"detail": "no reset is waiting"}
    assert _rows(store) == []
    store.request_scene_reset(run_id=run_id)
    assert client.get(f"/api/runs/{run_id}/robot").json()["reset_needed"] is True
    ready = client.post(f"/api/runs/{run_id}/robot/ready")
    assert ready.status_code == 200
    assert (ready.json()["reset_needed"], ready.json()["reset_count"]) == (False, 1)
    before = _rows(store)
    assert client.post(f"/api/runs/{run_id}/robot/ready").status_code == 409
    assert _rows(store) == before
    assert store.robot_status(run_id=run_id).reset_count == 1


def test_evaluate_now_is_202_then_409_while_pending_and_422_for_a_bad_count(client: TestClient, store: Store) -> None:
    run_id = _run(store)
    no_actor = client.post(f"/api/runs/{run_id}/robot/evaluate", json={"episodes": 3})
    assert no_actor.status_code == 409 and "no actor drives" in no_actor.json()["detail"]
    store.report_actor(run_id=run_id, state="acting")
    accepted = client.post(f"/api/runs/{run_id}/robot/evaluate", json={"episodes": 3})
    assert accepted.status_code == 202
    assert accepted.json()["run_id"] == run_id
    assert (accepted.json()["evaluation_pending"], accepted.json()["evaluation_round"]) == (3, 1)
    shown = client.get(f"/api/runs/{run_id}/robot").json()
    assert (shown["evaluation_pending"], shown["evaluation_round"]) == (3, 1)
    before = _rows(store)
    refused = client.post(f"/api/runs/{run_id}/robot/evaluate", json={"episodes": 1})
    assert refused.status_code == 409 and "not begun yet" in refused.json()["detail"]
    bad = [{"episodes": 0}, {"episodes": 21}, {"episodes": "many"}, {"episodes": 2.5}, {}, {"episodes": 2, "x": 1}]
    for body in bad:
        assert client.post(f"/api/runs/{run_id}/robot/evaluate", json=body).status_code == 422, body
    assert _rows(store) == before
    for _ in range(3):
        store.take_evaluation_episode(run_id=run_id)
    again = client.post(f"/api/runs/{run_id}/robot/evaluate", json={"episodes": 1})
    assert again.status_code == 202 and again.json()["evaluation_round"] == 2
    missing = client.post("/api/runs/404/robot/evaluate", json={"episodes": 1})
    assert missing.status_code == 404 and missing.json() == {"detail": "run 404 not found"}


def test_the_camera_is_404_before_a_frame_then_the_newest_png_never_cached(client: TestClient, store: Store) -> None:
    run_id = _run(store)
    missing = client.get(f"/api/runs/{run_id}/robot/camera")
    assert missing.status_code == 404 and "no camera frame yet" in missing.json()["detail"]
    assert missing.headers["cache-control"] == "no-store"
    store.report_actor(run_id=run_id, state="moving")  # a report without a frame: still none
    assert client.get(f"/api/runs/{run_id}/robot/camera").status_code == 404
    frame = _png()
    status = store.report_actor(run_id=run_id, state="moving", frame_png=frame)
    camera = client.get(f"/api/runs/{run_id}/robot/camera")
    assert camera.status_code == 200 and camera.content == frame
    assert camera.headers["content-type"] == "image/png" and camera.headers["cache-control"] == "no-store"
    shown = client.get(f"/api/runs/{run_id}/robot").json()
    assert shown["camera_url"].startswith(f"/api/runs/{run_id}/robot/camera?v=")
    assert client.get(shown["camera_url"]).content == frame
    newer = _png((200, 40, 40))
    later = store.report_actor(run_id=run_id, state="moving", frame_png=newer)
    assert client.get(f"/api/runs/{run_id}/robot/camera").content == newer
    if later.frame_at != status.frame_at:  # a new frame, a new URL: the page's <img> loads it
        assert client.get(f"/api/runs/{run_id}/robot").json()["camera_url"] != shown["camera_url"]


def test_api_robots_lists_the_active_runs_whose_actor_reported_recently(client: TestClient, store: Store) -> None:
    stale, live = _run(store, active=True), _run(store, active=True)
    queued = _run(store)
    assert client.get("/api/robots").json() == []
    for run_id in (stale, live, queued):
        store.report_actor(run_id=run_id, state="moving", frame_png=_png())
    store.request_scene_reset(run_id=live)
    assert [robot["run_id"] for robot in client.get("/api/robots").json()] == [stale, live]
    _age_actor(store, stale, 60)
    [robot] = client.get("/api/robots").json()
    assert robot["run_id"] == live and robot["reset_needed"] is True and robot["live"] is True
    assert robot["camera_url"].startswith(f"/api/runs/{live}/robot/camera?v=")


def test_an_unknown_run_is_404_and_a_bad_id_422_with_nothing_stored(client: TestClient, store: Store) -> None:
    for method, path in [
        ("GET", "robot"), ("POST", "robot/stop"), ("POST", "robot/resume"), ("POST", "robot/ready"),
        ("GET", "robot/camera"),
    ]:  # fmt: skip
        response = client.request(method, f"/api/runs/404/{path}")
        assert response.status_code == 404 and response.json() == {"detail": "run 404 not found"}, path
        for bad in ("0", "abc", "2147483648", "-1"):
            assert client.request(method, f"/api/runs/{bad}/{path}").status_code == 422, (bad, path)
    assert _rows(store) == []


def test_a_refused_change_stores_nothing(make_client: Callable[..., TestClient], store: Store) -> None:
    run_id = _run(store)
    store.request_scene_reset(run_id=run_id)
    before = _rows(store)
    client = make_client()
    cross_site = {"Origin": "https://elsewhere.example"}
    evaluate = {"episodes": 2}
    for action in ("stop", "resume", "ready", "evaluate"):
        refused = client.post(f"/api/runs/{run_id}/robot/{action}", headers=cross_site, json=evaluate)
        assert refused.status_code == 403, action
    locked = make_client(api_token="robot-secret")
    for action in ("stop", "resume", "ready", "evaluate"):
        assert locked.post(f"/api/runs/{run_id}/robot/{action}", json=evaluate).status_code == 401, action
    assert locked.get(f"/api/runs/{run_id}/robot").status_code == 401
    assert _rows(store) == before
    allowed = locked.post(f"/api/runs/{run_id}/robot/stop", headers={"Authorization": "Bearer robot-secret"})
    assert allowed.status_code == 200 and allowed.json()["stop_requested"] is True
