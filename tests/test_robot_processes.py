"""A robot's own process in the store (contract/store/robot_processes.py): its row, its frames for the pages, the
pages' watching, and the runs whose learner waits for it (Store.runs_awaiting_actor)."""

import io

import numpy as np
import pytest
from PIL import Image
from sqlalchemy import update

from contract.store import InvalidInput, RunStatus, Store
from contract.store.models import RobotControl, RobotProcess
from contract.store.robot_processes import ROBOT_PROCESS_LIVE_SECONDS, WATCHED_SECONDS

ENV_ID = "robot.standin:PusherStandIn-v0"
ROBOT = f"lab-1/{ENV_ID}"


def png(value: int) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(np.full((6, 8, 3), value, np.uint8)).save(buffer, format="PNG")
    return buffer.getvalue()


def age(store: Store, column: str, seconds: float, model: type = RobotProcess) -> None:
    """A column of every row as if stamped `seconds` ago (by the database's clock)."""
    with store.writing() as session:
        session.execute(update(model).values({column: store._db_now(seconds)}))


def test_a_robot_process_is_live_while_it_stamps_its_row_and_gone_when_it_ends(store: Store) -> None:
    assert store.robot_process_of(env_id=ENV_ID) is None
    status = store.report_robot_process(robot=ROBOT, env_id=ENV_ID, holder="7@lab-1", state="waiting for a learner")
    assert (status.robot, status.state, status.frame_age_seconds, status.watched) == (
        ROBOT, "waiting for a learner", None, False,
    )  # fmt: skip
    assert store.robot_process_of(env_id=ENV_ID).holder == "7@lab-1" and store.robot_process_frame(robot=ROBOT) is None
    assert store.robot_process_of(env_id="other:Arm-v0") is None

    store.report_robot_process(robot=ROBOT, env_id=ENV_ID, holder="7@lab-1", state="idle", frame_png=png(40))
    frame, _ = store.robot_process_frame(robot=ROBOT)
    assert frame == png(40)
    store.report_robot_process(robot=ROBOT, env_id=ENV_ID, holder="7@lab-1", state="driving run 3")
    assert store.robot_process_frame(robot=ROBOT)[0] == png(40)  # a stamp without a frame keeps the last one
    with pytest.raises(InvalidInput):
        store.report_robot_process(robot=ROBOT, env_id=ENV_ID, holder="7@lab-1", state="x", frame_png=b"GIF89a")
    assert store.robot_process_frame(robot=ROBOT)[0] == png(40)

    age(store, "seen_at", ROBOT_PROCESS_LIVE_SECONDS + 1)  # it crashed: its row stays, but it is not up
    assert store.robot_process_of(env_id=ENV_ID) is None and len(store.robot_processes()) == 1
    store.report_robot_process(robot=ROBOT, env_id=ENV_ID, holder="9@lab-1", state="waiting for a learner")
    assert store.robot_process_of(env_id=ENV_ID).holder == "9@lab-1"  # its restart takes the row over
    store.robot_process_ended(robot=ROBOT, holder="7@lab-1")  # (not its row any more: nothing changes)
    assert store.robot_process_of(env_id=ENV_ID) is not None
    store.robot_process_ended(robot=ROBOT, holder="9@lab-1")
    assert store.robot_process_of(env_id=ENV_ID) is None and store.robot_processes() == []


def test_a_page_asking_for_frames_marks_the_robot_watched_for_a_while(store: Store) -> None:
    store.report_robot_process(robot=ROBOT, env_id=ENV_ID, holder="7@lab-1", state="waiting for a learner")
    store.watch_robot(robot=ROBOT)
    assert store.robot_process_of(env_id=ENV_ID).watched
    age(store, "watched_at", WATCHED_SECONDS + 1)
    assert not store.robot_process_of(env_id=ENV_ID).watched


def test_the_runs_awaiting_an_actor_are_those_whose_learner_has_the_link_open_now(store: Store) -> None:
    runs = [store.create_run(name=name, env_id=ENV_ID, algorithm="vice_raq", config={}) for name in "abc"]
    other = store.create_run(name="other", env_id="other:Arm-v0", algorithm="vice_raq", config={})
    for _ in range(4):
        store.claim_next_run(worker="learner")
    for run in runs[:2] + [other]:
        store.heartbeat(run_id=run.id, worker="learner", step=0, status=RunStatus.TRAINING)
        store.open_actor_link(run_id=run.id, claim=store.run_claim(run_id=run.id), start_step=None)
    assert store.runs_awaiting_actor(env_id=ENV_ID) == [runs[0].id, runs[1].id]  # (c never opened one)
    assert store.runs_awaiting_actor(env_id=ENV_ID, run_id=runs[1].id) == [runs[1].id]
    store.close_actor_link(run_id=runs[0].id, claim=store.run_claim(run_id=runs[0].id))
    assert store.runs_awaiting_actor(env_id=ENV_ID) == [runs[1].id]  # its learner let go
    age(store, "learner_seen_at", 5.0, model=RobotControl)  # every learner silent: none waits now
    assert store.runs_awaiting_actor(env_id=ENV_ID) == []
    store.learner_keepalive(run_id=runs[1].id, claim=store.run_claim(run_id=runs[1].id))
    assert store.runs_awaiting_actor(env_id=ENV_ID) == [runs[1].id]
    store.set_run_status(run_id=runs[1].id, status=RunStatus.FINISHED)
    assert store.runs_awaiting_actor(env_id=ENV_ID) == []
