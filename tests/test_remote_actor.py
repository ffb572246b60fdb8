"""An actor on another host than its learner: `raq actor --run ID` drives the env from its own process, sharing only
the database URL and the checkpoint folder with the learner; the policy reaches it through the checkpoint store; a
killed learner leaves the arm held safe within the watchdog time, and the next learner drives the same actor."""

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

import pytest
import sqlalchemy as sa
import torch
from conftest import create_run, learn_once_beside
from recording_arm import ENV_ID, LOG_VARIABLE, recorded
from test_actor import real_time_config

from app.migrate import upgrade
from contract.actor_messages import PolicyWeights, Start, Transition, decode_message, encode_message
from contract.checkpoint_location import ACTOR_POLICY_FILENAME
from contract.settings import Settings
from contract.store import NotFound, RunStatus, Store
from learner.acting import SAC_ACTING
from learner.checkpoint import save_checkpoint
from robot.drive.actor import ActorState
from robot.drive.link import StoreLink

ROOT = Path(__file__).resolve().parent.parent
LINK_SLACK_SECONDS = 0.5
"""How much later than the watchdog time a remote actor may hold the arm: the learner's last keep-alive reaches it
through the database (written every 0.25 s, read every 0.05 s)."""


def host_env(settings: Settings) -> dict[str, str]:
    """What a host of this deployment is given: the database URL and the data (checkpoint) folder."""
    env = dict(os.environ, RAQ_DATA_DIR=str(settings.data_dir), RAQ_DATABASE_URL=settings.resolved_database_url)
    env.update(OMP_NUM_THREADS="1", MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    return env


def wait_until(condition, seconds: float, what: str, process: subprocess.Popen | None = None) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + seconds
    while not condition():
        assert process is None or process.poll() is None, f"{what}: the process exited"
        assert time.monotonic() < deadline, f"not within {seconds} s: {what}"
        time.sleep(0.02)


def test_messages_keep_their_images_arrays_and_info_through_the_database() -> None:
    import numpy as np  # noqa: PLC0415

    observation = np.random.default_rng(0).integers(0, 256, (16, 16, 3), dtype=np.uint8)
    display = np.full((32, 32, 3), 7, dtype=np.uint8)
    action = np.array([0.25, -1.0], dtype=np.float32)
    message = Transition(action, observation, 0.5, False, True, {"success": 1.0, "pos": np.zeros(2)}, display, 0.2, 3)
    kind, payload, observation_png, display_png = encode_message(message)
    decoded = decode_message(kind, payload, observation_png, display_png)
    assert isinstance(decoded, Transition) and kind == "step"
    assert (decoded.reward, decoded.terminated, decoded.truncated) == (0.5, False, True)
    assert decoded.info == {"success": 1.0, "pos": [0.0, 0.0]}
    assert (decoded.period, decoded.evaluation_round) == (0.2, 3)
    assert np.array_equal(decoded.action, action) and decoded.action.dtype == np.float32
    assert np.array_equal(decoded.observation, observation) and np.array_equal(decoded.display, display)


@pytest.fixture(params=["sqlite", "postgresql"])
def link_store(request: pytest.FixtureRequest, database_url: str) -> Iterator[Store]:
    url = database_url if request.param == "sqlite" else request.getfixturevalue("postgres_url")
    if request.param == "postgresql":
        upgrade(url)
    opened = Store(url)
    yield opened
    opened.dispose()


def test_the_link_carries_the_actors_messages_in_order_and_the_learners_side(link_store: Store) -> None:
    store = link_store
    run_id = store.create_run(env_id="robot.standin:PusherStandIn-v0", algorithm="vice_raq", config={}).id
    link = store.open_actor_link(run_id=run_id, claim=0, start_step=None)
    assert link.start_step is None and not link.learner_closed and link.actor_spaces is None
    assert link.learner_age_seconds is not None and 0 <= link.learner_age_seconds < 2
    store.announce_actor(run_id=run_id, spaces={"control_hz": 5.0})
    store.report_actor(run_id=run_id, state="acting")
    store.start_actor_link(run_id=run_id, claim=0, start_step=1200)
    link = store.actor_link(run_id=run_id)
    assert link.start_step == 1200 and link.actor_spaces == {"control_hz": 5.0}
    assert link.actor_age_seconds is not None and link.actor_age_seconds < 2
    assert [store.publish_actor_policy(run_id=run_id, claim=0) for _ in range(2)] == [1, 2]

    cursor, seen = 0, []
    for batch in (["a", "b", "c"], ["d"], ["e", "f"]):  # each batch taken whole before the next is posted
        store.post_actor_messages(run_id=run_id, messages=[("state", {"items": [name]}, None, None) for name in batch])
        taken = store.take_actor_messages(run_id=run_id, after_id=cursor)
        assert store.take_actor_messages(run_id=run_id, after_id=taken[-1].id) == []
        seen += [message.payload["items"][0] for message in taken]
        cursor = taken[-1].id
    assert seen == ["a", "b", "c", "d", "e", "f"]

    store.close_actor_link(run_id=run_id, claim=0)
    link = store.actor_link(run_id=run_id)
    assert link.learner_closed and link.start_step is None and link.policy_version == 2
    with pytest.raises(NotFound):
        store.actor_link(run_id=run_id + 1)


def taken_over(store: Store) -> tuple[int, int, int]:
    """A run claimed by a first learner, which opened its link and got three steps, then claimed by a second once
    the first's heartbeat is old: (the run, the first claim, the second)."""
    run_id = store.create_run(
        env_id="robot.standin:PusherStandIn-v0", algorithm="vice_raq", config={}, priority=100
    ).id  # (claimed first, before any other run of the module's database)
    first = store.claim_next_run(worker="first")
    assert first is not None and first.id == run_id
    old_claim = store.run_claim(run_id=run_id)
    store.open_actor_link(run_id=run_id, claim=old_claim, start_step=None)
    store.post_actor_messages(run_id=run_id, messages=[("state", {"items": [n]}, None, None) for n in "abc"])
    with store.engine.begin() as connection:  # the first learner's heartbeat is old: the run is taken over
        connection.execute(sa.text("UPDATE runs SET heartbeat_at = '2000-01-01 00:00:00.000000' WHERE id = :id"),
                           {"id": run_id})  # fmt: skip
    second = store.claim_next_run(worker="second")
    assert second is not None and second.id == run_id
    new_claim = store.run_claim(run_id=run_id)
    assert new_claim == old_claim + 1
    store.open_actor_link(run_id=run_id, claim=new_claim, start_step=None)
    return run_id, old_claim, new_claim


def test_a_learner_whose_run_was_claimed_again_writes_nothing_on_the_link(link_store: Store) -> None:
    """The displaced learner (it stalled past the staleness limit, another claimed its run) neither closes, stamps
    nor publishes on the new learner's link, nor forgets steps its own checkpoint lacks."""
    store = link_store
    run_id, old_claim, new_claim = taken_over(store)
    store.start_actor_link(run_id=run_id, claim=new_claim, start_step=40)
    version = store.publish_actor_policy(run_id=run_id, claim=new_claim)

    assert store.close_actor_link(run_id=run_id, claim=old_claim) is False
    assert store.publish_actor_policy(run_id=run_id, claim=old_claim) is None
    assert store.learner_keepalive(run_id=run_id, claim=old_claim) is False
    assert store.start_actor_link(run_id=run_id, claim=old_claim, start_step=0) is False
    newest = store.newest_actor_message(run_id=run_id)
    assert store.forget_actor_messages(run_id=run_id, claim=old_claim, checkpointed_id=newest) == 0
    link = store.actor_link(run_id=run_id)
    assert not link.learner_closed and link.start_step == 40 and link.policy_version == version
    assert len(store.take_actor_messages(run_id=run_id, after_id=0)) == 3
    assert store.learner_keepalive(run_id=run_id, claim=new_claim) is True


def test_an_actor_loads_no_policy_a_displaced_learner_wrote(link_store: Store, tmp_path: Path) -> None:
    """The checkpoint store's policy file is written over by the displaced learner after the new one published its
    version: the actor skips it (it names the other claim) and loads the new learner's next one."""
    store = link_store
    run_id, old_claim, new_claim = taken_over(store)
    store.start_actor_link(run_id=run_id, claim=new_claim, start_step=40)
    policy_url = str(tmp_path / ACTOR_POLICY_FILENAME)
    link = StoreLink(store, run_id=run_id, policy_url=policy_url, hz=5.0, read_weights=SAC_ACTING.read_weights)
    received: list[object] = []

    def receive(seconds: float) -> list[object]:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            while link.poll():
                received.append(link.recv())
            time.sleep(0.02)
        return [message for message in received if isinstance(message, PolicyWeights)]

    try:
        assert receive(1.0) == [] and [m.claim for m in received if isinstance(m, Start)] == [new_claim]
        save_checkpoint(policy_url, {"version": 1, "claim": old_claim, "modules": {"actor": {"w": torch.zeros(1)}}})
        assert store.publish_actor_policy(run_id=run_id, claim=new_claim) == 1
        assert receive(0.5) == []  # (the displaced learner's weights, under the new learner's version)
        save_checkpoint(policy_url, {"version": 2, "claim": new_claim, "modules": {"actor": {"w": torch.ones(1)}}})
        assert store.publish_actor_policy(run_id=run_id, claim=new_claim) == 2
        loaded = receive(1.0)
        assert len(loaded) == 1 and float(loaded[0].modules["actor"]["w"]) == 1.0
    finally:
        link.close()


def test_a_remote_actor_drives_the_robot_for_each_learner_and_holds_it_when_one_is_killed(
    dot_reach: tuple[Settings, Store, int], tmp_path: Path
) -> None:
    """On an arm that records its calls: a SIGKILLed learner's remote actor holds the arm (hold_safe) within the
    watchdog time, the keep-alive's trip through the database aside, and sends no action until the next learner."""
    settings, store, goal_set_id = dot_reach
    log = tmp_path / "arm.log"
    config = real_time_config(env_id=ENV_ID, remote_actor=True, total_steps=300, checkpoint_every=50)
    run_id = create_run(store, goal_set_id, config)
    env = host_env(settings)
    env.update({
        LOG_VARIABLE: str(log), "RAQ_ENV_MODULES": "learner.testing_envs,recording_arm",
        "PYTHONPATH": str(ROOT / "tests"),
    })  # fmt: skip
    actor = subprocess.Popen(
        [sys.executable, "-m", "cli", "actor", "--run", str(run_id)], cwd=ROOT, env=env, stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )  # fmt: skip
    learner_log = (settings.data_dir / "learner.log").open("wb")
    learner = subprocess.Popen(
        [sys.executable, "-m", "learner.worker", "--once", "--name", "doomed"], cwd=ROOT, env=env,
        stdout=learner_log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    done = threading.Event()
    person = threading.Thread(target=reset_and_answer, args=(store, run_id, done), daemon=True)
    person.start()
    output = ""
    try:
        # the first learner: the actor's steps reach it through the database, its policy the actor through the
        # checkpoint folder
        wait_until(lambda: store.get_run(run_id=run_id).step >= 100, 120, "the first learner's steps", learner)
        wait_until(lambda: store.actor_link(run_id=run_id).policy_version >= 2, 30, "a policy sent", learner)
        assert (settings.checkpoint_dir / f"run-{run_id}" / ACTOR_POLICY_FILENAME).exists()
        learner.send_signal(signal.SIGKILL)
        killed = time.monotonic()
        learner.wait(timeout=10)
        holds = lambda: [at for what, at in recorded(log) if what == "hold" and at > killed]  # noqa: E731
        wait_until(lambda: bool(holds()), 5, "the arm held after the learner's SIGKILL", actor)
        held = holds()[0]
        assert held - killed < config.watchdog_seconds + LINK_SLACK_SECONDS, held - killed
        wait_until(
            lambda: store.robot_status(run_id=run_id).actor_state == ActorState.LEARNER_GONE, 5,
            "the page to say the arm is held", actor,
        )  # fmt: skip
        time.sleep(1.0)  # the arm stays held, and the page says why, until the next learner
        assert store.robot_status(run_id=run_id).actor_state == ActorState.LEARNER_GONE and actor.poll() is None
        assert [at for what, at in recorded(log) if what == "action" and at > held] == []
        # the next learner takes the run over (its heartbeat went stale) and drives the same actor to the end
        quick = settings.model_copy(update={"stale_heartbeat_seconds": 1.0})
        time.sleep(1.5)
        assert learn_once_beside(quick, lambda stop: stop.wait()) == 0
        assert store.get_run(run_id=run_id).status == RunStatus.FINISHED
        assert store.get_run(run_id=run_id).step == config.total_steps
        output = actor.communicate(timeout=30)[0].decode()
    finally:
        done.set()
        output = end_learner_and_actor(learner, actor, learner_log, output)
    assert actor.returncode == 0, output
    assert f"arm {ActorState.LEARNER_GONE}" in output
    assert "run finished" in output
    assert store.robot_status(run_id=run_id).actor_state == ActorState.CLOSED


def reset_and_answer(store: Store, run_id: int, done: threading.Event) -> None:
    """A person at the page: Ready whenever a reset is asked for, every query answered truthfully."""
    while not done.is_set():
        if store.robot_status(run_id=run_id).reset_needed:
            store.scene_ready(run_id=run_id)
        for query in store.pending_queries(run_id=run_id):
            store.answer_query(query_id=query.id, success=bool(query.ground_truth_success), labeler="oracle")
        time.sleep(0.02)


def end_learner_and_actor(
    learner: subprocess.Popen, actor: subprocess.Popen | None, learner_log: BinaryIO, output: str
) -> str:
    """Kill what still runs; print both outputs (the actor's, read here unless given, and the learner's log)."""
    for process in (learner, actor):
        if process is not None and process.poll() is None:
            process.kill()
    if actor is not None:
        output = output or actor.communicate(timeout=30)[0].decode()
    learner.wait(timeout=30)
    learner_log.close()
    print("actor:", output, "learner:", Path(learner_log.name).read_text(), sep="\n")
    return output
