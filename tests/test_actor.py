"""The real-time actor: the env steps at its own rate in its own process while the learner trains; a person's
reset before each episode, Stop robot and Resume through the store; the watchdog holds the arm when the learner is
killed or the database goes away. A robot (the recording arm) is driven by its own process (`raq robot`, here on a
thread of the test or in a process of its own), a simulated env given a control_hz by a process beside its
learner."""

import functools
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from conftest import create_run, learn_once_beside, robot_serving, robot_subprocess
from pg_server import PostgresServer
from recording_arm import ENV_ID, LOG_VARIABLE, recorded
from test_learner_run import tiny_config

from app.migrate import upgrade
from contract.config import TrainConfig
from contract.settings import Settings, get_settings
from contract.store import RunStatus, Store
from learner.checkpoint import checkpoint_path, load_checkpoint
from learner.testing_envs import add_dot_goals
from learner.worker import work
from robot.drive.actor import ActorState

ROOT = Path(__file__).resolve().parent.parent
HZ = 40.0


def real_time_config(**overrides: object) -> TrainConfig:
    """The learner tests' tiny run, in real time at HZ with a person's reset before every episode."""
    values: dict[str, object] = dict(
        total_steps=200, query_budget=3, control_hz=HZ, reset_every_episode=True, updates_per_step=2,
        policy_sync_seconds=0.2,
    )  # fmt: skip
    return tiny_config(**{**values, **overrides})


@pytest.fixture
def setup(dot_reach: tuple[Settings, Store, int]) -> tuple[Settings, Store, int]:
    return dot_reach


def resetter_and_oracle(store: Store, run_id: int, done: threading.Event, *, presses: list[float]) -> None:
    """A person who presses Ready whenever the actor asks for a reset, and answers every query truthfully."""
    while not done.is_set():
        if store.robot_status(run_id=run_id).reset_needed:
            store.scene_ready(run_id=run_id)
            presses.append(time.monotonic())
        for query in store.pending_queries(run_id=run_id):
            store.answer_query(query_id=query.id, success=bool(query.ground_truth_success), labeler="oracle")
        time.sleep(0.02)


def test_real_time_run_trains_beside_its_actor_with_a_reset_before_every_episode(
    setup: tuple[Settings, Store, int],
) -> None:
    settings, store, goal_set_id = setup
    config = real_time_config()
    run_id = create_run(store, goal_set_id, config)
    presses: list[float] = []
    assert learn_once_beside(settings, functools.partial(resetter_and_oracle, store, run_id, presses=presses)) == 0
    run = store.get_run(run_id=run_id)
    assert run.status == RunStatus.FINISHED, run.status_reason
    assert run.step == config.total_steps
    episodes = config.total_steps // config.episode_steps
    assert store.robot_status(run_id=run_id).reset_count >= episodes  # one Ready before every episode
    names = {metric.name for metric in store.metrics(run_id=run_id)}
    assert {"actor/period_ms_p99", "critic/loss", "reward/loss", "queries/asked"} <= names
    periods = [m.value for m in store.metrics(run_id=run_id, names=["actor/period_ms_mean"])]
    assert periods and all(value >= 0.9 * 1000 / HZ for value in periods), periods  # never faster than its rate
    # (on a busy machine a late step is sent late and the period restarts from it: tests/test_actor_pace.py)
    updates = [m.value for m in store.metrics(run_id=run_id, names=["perf/updates_per_second"])]
    assert updates and max(updates) > 0
    messages = [event.message for event in store.events(run_id=run_id, limit=1000)]
    assert f"robot: {ActorState.WAITING_FOR_RESET}" in messages
    assert store.camera_frame(run_id=run_id) is not None  # the live view was published
    state = load_checkpoint(checkpoint_path(settings.checkpoint_dir, run_id))
    assert state is not None  # the updates beside the actor: some, and never more than the cap per env step
    assert 0 < state["total_updates"] <= (config.total_steps - config.initial_random_steps + 1) * 2


def test_stop_robot_holds_the_arm_within_a_period_and_resume_continues(
    setup: tuple[Settings, Store, int], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """On an arm that records its calls: Stop robot holds it within one control period (hold_safe called) and no
    action follows until Resume; Resume starts a new episode (the arm home first) and the run goes on."""
    settings, store, goal_set_id = setup
    log = tmp_path / "arm.log"
    monkeypatch.setenv(LOG_VARIABLE, str(log))  # (the actor process inherits both)
    monkeypatch.setenv("RAQ_ENV_MODULES", "learner.testing_envs,recording_arm")
    get_settings.cache_clear()
    config = real_time_config(
        env_id=ENV_ID, total_steps=400, control_hz=5.0, reset_every_episode=False, episode_steps=1000
    )  # fmt: skip
    period = 1.0 / config.control_hz

    def times(kind: str, after: float = 0.0) -> list[float]:
        return [at for what, at in recorded(log) if what == kind and at > after]

    run_id = create_run(store, goal_set_id, config)
    learner = threading.Thread(target=work, args=(settings,), kwargs={"worker_name": "w", "once": True})
    robot = robot_serving(store, ENV_ID, settings.checkpoint_dir)
    robot.__enter__()
    learner.start()
    try:
        wait_for(lambda: len(times("action")) >= 5 or not learner.is_alive(), 120, "the arm to move")
        assert learner.is_alive()
        asked = time.monotonic()
        store.request_robot_stop(run_id=run_id)
        wait_for(lambda: bool(times("hold", after=asked)), 5, "the arm to be held")
        held = times("hold", after=asked)[0]
        assert held - asked < period, held - asked  # within a control period
        wait_for(lambda: store.robot_status(run_id=run_id).actor_state == ActorState.STOPPED, 5, "the state")
        time.sleep(1.0)  # the learner takes the steps the actor sent before the stop (heartbeats carry its step)
        step = store.get_run(run_id=run_id).step
        time.sleep(1.5)  # stopped: no env step is taken
        assert store.get_run(run_id=run_id).step == step
        resumed = time.monotonic()
        assert times("action", after=held) == []  # the arm stayed still until Resume
        store.resume_robot(run_id=run_id)
        wait_for(lambda: store.get_run(run_id=run_id).step > step, 30, "the run to continue after Resume")
        assert times("reset", after=resumed)[0] < times("action", after=resumed)[0]  # a new episode, arm home first
    finally:
        store.request_stop(run_id=run_id)
        learner.join(timeout=180)
        robot.__exit__(None, None, None)
        get_settings.cache_clear()
    messages = [event.message for event in store.events(run_id=run_id, limit=1000)]
    assert f"robot: {ActorState.STOPPED}" in messages


def arm_env(settings: Settings, log: Path, database_url: str | None = None) -> dict[str, str]:
    """The environment of a learner or robot subprocess for a run on the recording arm that writes to `log`: the
    store (`database_url`, else the settings'), the data folder, the arm's module."""
    database_url = database_url or settings.resolved_database_url
    env = dict(os.environ, RAQ_DATA_DIR=str(settings.data_dir), RAQ_DATABASE_URL=database_url)
    env.update(
        OMP_NUM_THREADS="1", RAQ_ENV_MODULES="learner.testing_envs,recording_arm", PYTHONPATH=f"{ROOT / 'tests'}",
    )  # fmt: skip
    env[LOG_VARIABLE] = str(log)
    return env


def test_a_killed_learners_actor_holds_the_arm_sends_nothing_more_and_waits_for_the_next(
    setup: tuple[Settings, Store, int], tmp_path: Path
) -> None:
    """The robot's own process drives the run of a learner that is SIGKILLed: the arm is held within the watchdog
    time, no action follows the hold, and the process waits for the next learner, the arm held. Each step is larger
    than a pipe's buffer (a 256-pixel view), as a robot camera's are."""
    settings, store, goal_set_id = setup
    log = tmp_path / "arm.log"
    config = real_time_config(
        env_id=ENV_ID, control_hz=10.0, total_steps=100_000, reset_every_episode=False, episode_steps=1000,
        display_size=256,
    )  # fmt: skip
    run_id = create_run(store, goal_set_id, config)
    env = arm_env(settings, log)
    with robot_subprocess(env, ENV_ID, store, tmp_path / "robot.log") as robot:
        learner = subprocess.Popen(
            [sys.executable, "-m", "learner.worker", "--once", "--name", "doomed"], cwd=ROOT, env=env,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        )  # fmt: skip
        try:
            wait_for(
                lambda: learner.poll() is not None or store.get_run(run_id=run_id).step >= 5, 120, "the run's steps"
            )
            assert learner.poll() is None, learner.communicate(timeout=30)[0].decode()
            learner.send_signal(signal.SIGKILL)
            killed = time.monotonic()
            wait_for(lambda: any(what == "hold" for what, _ in recorded(log)), 5, "the arm to be held")
            held = next(at for what, at in recorded(log) if what == "hold")
            assert held - killed < config.watchdog_seconds + 0.5  # (the last keep-alive crosses the store)
            wait_for(
                lambda: store.robot_process_of(env_id=ENV_ID).state == "waiting for a learner", 10,
                "the robot's process to wait for the next learner",
            )  # fmt: skip
            time.sleep(1.0)
            assert [at for what, at in recorded(log) if what == "action" and at > held] == []
            assert robot.poll() is None
        finally:
            if learner.poll() is None:
                learner.kill()
            learner.communicate(timeout=30)
    assert f"arm {ActorState.LEARNER_GONE}" in (tmp_path / "robot.log").read_text()


def wait_for(condition: Callable[[], bool], seconds: float, what: str) -> None:
    """Poll `condition` until it holds; fail after `seconds`."""
    deadline = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < deadline, f"waited {seconds:g} s for {what}"
        time.sleep(0.01)


def test_a_database_outage_holds_the_arm_safe_until_a_person_resumes(tmp_path: Path) -> None:
    """PostgreSQL stopped under a real-time run: the arm is held within the watchdog time and sends no action;
    once the database is back the run's robot shows stopped, and only Resume lets the arm move again."""
    log = tmp_path / "arm.log"
    config = real_time_config(
        env_id=ENV_ID, control_hz=10.0, total_steps=100_000, reset_every_episode=False, episode_steps=1000,
    )  # fmt: skip
    limit = config.watchdog_seconds

    def times(kind: str, after: float = 0.0) -> list[float]:
        return [at for what, at in recorded(log) if what == kind and at > after]

    with pytest.MonkeyPatch.context() as patch, PostgresServer.started() as server:
        patch.setenv(LOG_VARIABLE, str(log))  # (the actor process inherits both)
        patch.setenv("RAQ_ENV_MODULES", "learner.testing_envs,recording_arm")
        get_settings.cache_clear()
        upgrade(server.url)
        store = Store(server.url)
        run_id = create_run(store, add_dot_goals(store), config)
        settings = Settings(data_dir=tmp_path, database_url=server.url, stale_heartbeat_seconds=60.0)
        learner = threading.Thread(target=work, args=(settings,), kwargs={"worker_name": "w", "once": True})
        robot = robot_serving(store, ENV_ID, settings.checkpoint_dir)
        robot.__enter__()
        learner.start()
        down = False
        try:
            wait_for(lambda: len(times("action")) >= 5, 120, "the arm to move")
            outage = time.monotonic()
            server.stop()
            down, stopped = True, time.monotonic()
            wait_for(lambda: bool(times("hold")), limit + 5, "the arm to be held")
            held = times("hold")[0]
            assert outage < held < stopped + limit + 0.5, (held - stopped, limit)  # in time, and not before
            time.sleep(0.5)  # away a while longer
            server.start()
            down = False
            wait_for(lambda: store.robot_status(run_id=run_id).stop_requested, 15, "the robot to be marked stopped")
            time.sleep(0.5)  # the database is back, the robot stopped: the arm stays still
            resumed = time.monotonic()
            assert times("action", after=held) == []  # none while the database was away, nor since
            store.resume_robot(run_id=run_id)
            wait_for(lambda: bool(times("action", after=resumed)), 15, "the arm to move after Resume")
            assert times("reset", after=held)[0] < times("action", after=held)[0]  # a new episode began
            acting = lambda: store.robot_status(run_id=run_id).actor_state == ActorState.ACTING  # noqa: E731
            wait_for(acting, 5, "the robot to show acting")
            held_event = f"robot: {ActorState.DATABASE_GONE}"
            events = lambda: [event.message for event in store.events(run_id=run_id, limit=1000)]  # noqa: E731
            wait_for(lambda: held_event in events(), 60, "the run's events to tell of the hold")
        finally:
            if down:  # (a failed check: the learner is let go all the same)
                server.start()
            store.request_stop(run_id=run_id)
            learner.join(timeout=180)
            robot.__exit__(None, None, None)
        run = store.get_run(run_id=run_id)
        assert run.status == RunStatus.STOPPED, run.status_reason  # the actor never failed
        store.dispose()
    get_settings.cache_clear()
