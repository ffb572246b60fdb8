"""No robot step is lost when a learner dies: an actor's steps (the robot's own process, `raq robot` or `raq actor`)
stay in the store until a checkpoint holds them, and the learner that takes the run over adds those taken after its
checkpoint to its replay, in order and once each, before the actor starts again."""

import functools
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from action_values_arm import ACTIONS_VARIABLE, actions_sent
from action_values_arm import ENV_ID as ARM_ID
from conftest import create_run, learn_once_beside
from recording_arm import LOG_VARIABLE, recorded
from recording_arm import recorded_by as calls_of
from test_actor import real_time_config
from test_remote_actor import (  # noqa: F401 - link_store: a fixture
    end_learner_and_actor,
    host_env,
    link_store,
    reset_and_answer,
    wait_until,
)

from contract.settings import Settings, get_settings
from contract.store import RunStatus, Store
from learner.checkpoint import checkpoint_path, load_checkpoint

ROOT = Path(__file__).resolve().parent.parent
TOTAL_STEPS, CHECKPOINT_EVERY, WATCHDOG_SECONDS, STALE_SECONDS = 250, 80, 1.0, 1.0
SAME_ACTION = 1e-5
"""Two actions closer than this in every dimension are the same (the arm is sent the policy's action rescaled)."""


def test_the_actors_messages_are_kept_until_a_checkpoint_holds_them(link_store: Store) -> None:  # noqa: F811
    store = link_store
    run_id = store.create_run(env_id="robot.standin:PusherStandIn-v0", algorithm="vice_raq", config={}).id
    other = store.create_run(env_id="robot.standin:PusherStandIn-v0", algorithm="vice_raq", config={}).id
    store.open_actor_link(run_id=run_id, claim=0, start_step=None)

    def post(run: int, items: list[str]) -> None:
        store.post_actor_messages(run_id=run, messages=[("state", {"items": [item]}, None, None) for item in items])

    def names(after: int) -> list[str]:
        return [m.payload["items"][0] for m in store.take_actor_messages(run_id=run_id, after_id=after)]

    post(run_id, ["a", "b", "c", "d", "e", "f"])
    post(other, ["x"])
    ids = [message.id for message in store.take_actor_messages(run_id=run_id, after_id=0)]
    assert names(ids[-1]) == []
    # taking deletes none, nor does a learner that opens the link anew: each is there for the next learner
    store.open_actor_link(run_id=run_id, claim=0, start_step=None)
    assert names(0) == ["a", "b", "c", "d", "e", "f"]
    # a checkpoint holds the first four: the store forgets those before the fourth (the row the checkpoint's id
    # names stays: SQLite numbers a new row after the highest left), and the rest stay until a checkpoint holds them
    assert store.forget_actor_messages(run_id=run_id, claim=0, checkpointed_id=ids[3]) == 3
    assert names(0) == ["d", "e", "f"] and names(ids[3]) == ["e", "f"]
    assert store.forget_actor_messages(run_id=run_id, claim=0, checkpointed_id=ids[-1]) == 2
    assert store.newest_actor_message(run_id=run_id) == ids[-1]  # (where a learner that takes the run over reads to)
    post(run_id, ["g"])
    assert names(ids[-1]) == ["g"] and names(0) == ["f", "g"]
    assert [m.payload["items"] for m in store.take_actor_messages(run_id=other, after_id=0)] == [["x"]]
    third = store.create_run(env_id="robot.standin:PusherStandIn-v0", algorithm="vice_raq", config={}).id
    assert store.newest_actor_message(run_id=third) == 0


def alive(pid: int) -> bool:
    """The process runs (a zombie, ended but not yet reaped by its parent, does not)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.parametrize("remote_actor", [False, True], ids=["robot-process", "remote-actor"])
def test_a_learner_that_takes_a_run_over_trains_on_every_step_the_robot_took(
    dot_reach: tuple[Settings, Store, int], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, remote_actor: bool
) -> None:
    """The learner is SIGKILLed between two checkpoints; the robot went on until its actor held it. The robot's
    process (`raq robot`, or `raq actor --run ID` with remote_actor) drives the next learner. The learner that
    takes the run over has every action the arm sent before it in its replay, in
    order, none twice; no process that drove the arm is left."""
    settings, store, goal_set_id = dot_reach
    log, actions_log = tmp_path / "arm.log", tmp_path / "actions.log"
    config = real_time_config(
        env_id=ARM_ID, remote_actor=remote_actor, reset_every_episode=False, total_steps=TOTAL_STEPS,
        checkpoint_every=CHECKPOINT_EVERY, watchdog_seconds=WATCHDOG_SECONDS,
    )  # fmt: skip
    run_id = create_run(store, goal_set_id, config)
    # killed a random number of robot steps after its first checkpoint: well before its second (2 s at 40 Hz)
    kill_after = random.uniform(5, 30) / config.control_hz
    print(f"the first learner is killed {kill_after:.3f} s after its first checkpoint")
    env = host_env(settings)
    arm = {LOG_VARIABLE: str(log), ACTIONS_VARIABLE: str(actions_log)}
    modules = {"RAQ_ENV_MODULES": "learner.testing_envs,recording_arm,action_values_arm"}
    env.update({**arm, **modules, "PYTHONPATH": str(ROOT / "tests")})
    for name, value in {**arm, **modules}.items():  # (the second learner's actor, started from this process)
        monkeypatch.setenv(name, value)
    get_settings.cache_clear()
    serve = ["actor", "--run", str(run_id)] if remote_actor else ["robot", ARM_ID]
    actor = subprocess.Popen(
        [sys.executable, "-m", "cli", *serve], cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT
    )
    learner_log = (tmp_path / "learner.log").open("wb")
    learner = subprocess.Popen(
        [sys.executable, "-m", "learner.worker", "--once", "--name", "doomed"], cwd=ROOT, env=env,
        stdout=learner_log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    output = ""
    try:
        checkpoint_file = checkpoint_path(settings.checkpoint_dir, run_id)
        wait_until(checkpoint_file.exists, 120, "the first learner's first checkpoint", learner)
        time.sleep(kill_after)
        learner.send_signal(signal.SIGKILL)
        killed = time.monotonic()
        learner.wait(timeout=10)
        checkpoint = load_checkpoint(checkpoint_file)
        assert checkpoint is not None and checkpoint["step"] == CHECKPOINT_EVERY
        held = lambda: [at for what, at in recorded(log) if what == "hold" and at > killed]  # noqa: E731
        wait_until(lambda: bool(held()), 10, "the arm held after the learner's SIGKILL", actor)
        first_drivers = {pid for _, _, pid in calls_of(log)}
        time.sleep(max(0.0, killed + 1.5 * STALE_SECONDS - time.monotonic()))  # (its heartbeat stale: no race)
        second_started = time.monotonic()
        quick = settings.model_copy(update={"stale_heartbeat_seconds": STALE_SECONDS})
        assert learn_once_beside(quick, functools.partial(reset_and_answer, store, run_id)) == 0
        assert store.get_run(run_id=run_id).status == RunStatus.FINISHED
        if not remote_actor:  # (`raq robot` serves the robot until it is stopped; `raq actor` ends with its run)
            actor.send_signal(signal.SIGINT)
        output = actor.communicate(timeout=30)[0].decode()
        assert first_drivers == {actor.pid}  # the robot's own process drove it for both learners
        assert not any(alive(pid) for _, _, pid in calls_of(log)), "a process that drove the arm is left"
    finally:
        output = end_learner_and_actor(learner, actor, learner_log, output)
        get_settings.cache_clear()
    final = load_checkpoint(checkpoint_path(settings.checkpoint_dir, run_id))
    assert final is not None and final["step"] == TOTAL_STEPS
    replay = final["replay"]["actions"].numpy().astype(np.float64)
    assert final["replay"]["added"] == len(replay) == TOTAL_STEPS
    sent = actions_sent(actions_log, before=second_started)  # every action the robot took before the takeover
    assert CHECKPOINT_EVERY < len(sent) < TOTAL_STEPS
    same = np.abs(sent[:, None, :] - replay[None, :, :]).max(axis=-1) < SAME_ACTION
    lost, twice = int((same.sum(axis=1) == 0).sum()), int((same.sum(axis=1) > 1).sum())
    assert (lost, twice) == (0, 0), f"of the {len(sent)} actions sent, {lost} are not in the replay, {twice} twice"
    np.testing.assert_allclose(replay[: len(sent)], sent, atol=SAME_ACTION)  # in the order the arm sent them
    assert (np.abs(replay[:, None, :] - replay[None, :, :]).max(axis=-1) < SAME_ACTION).sum() == TOTAL_STEPS
    events = [event.message for event in store.events(run_id=run_id, limit=1000)]
    assert any(f"after step {CHECKPOINT_EVERY} (kept in the store" in message for message in events), events
    # the store forgot the steps the last checkpoint holds, all but the one its id names
    assert store.take_actor_messages(run_id=run_id, after_id=0)[0].id == final["actor_message"]
