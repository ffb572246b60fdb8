"""A robot's own process (robot/drive/process.py) and the learners of its env: a learner links to it whenever it is
up and never makes the env itself; an error of the robot fails the run with that error, and the process holds the
arm and serves the next run; it serves runs of other image sizes than it was made with."""

import threading
import time
from pathlib import Path

import pytest
from conftest import create_run, learn_once_beside, robot_serving
from recording_arm import ENV_ID, JAM_AT, JAMMING_ENV_ID, LOG_VARIABLE, recorded_by
from test_actor import real_time_config

from contract.settings import Settings, get_settings
from contract.store import RunStatus, Store


@pytest.fixture
def arm_log(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    log = tmp_path / "arm.log"
    monkeypatch.setenv(LOG_VARIABLE, str(log))
    monkeypatch.setenv("RAQ_ENV_MODULES", "learner.testing_envs,recording_arm")
    get_settings.cache_clear()
    yield log
    get_settings.cache_clear()


def presser(store: Store, run_id: int):  # type: ignore[no-untyped-def]
    """A person who presses Ready whenever the actor asks for a reset."""

    def press(done: threading.Event) -> None:
        while not done.wait(0.05):
            if store.robot_status(run_id=run_id).reset_needed:
                store.scene_ready(run_id=run_id)

    return press


def test_a_jammed_arm_fails_its_run_with_the_robots_error_and_the_process_serves_the_next_run(
    dot_reach: tuple[Settings, Store, int], arm_log: Path, tmp_path: Path
) -> None:
    settings, store, goal_set_id = dot_reach
    config = real_time_config(env_id=JAMMING_ENV_ID, total_steps=100_000, reset_every_episode=False, episode_steps=1000)
    with robot_serving(store, JAMMING_ENV_ID, settings.checkpoint_dir):
        run_id = create_run(store, goal_set_id, config)
        assert learn_once_beside(settings, presser(store, run_id)) == 1  # (a run failed)
        run = store.get_run(run_id=run_id)
        assert run.status == RunStatus.FAILED and "RuntimeError: the gripper jammed" in run.status_reason, run
        calls = recorded_by(arm_log)
        driver = {pid for what, _, pid in calls if what == "action"}
        assert len(driver) == 1 and [what for what, _, _ in calls].count("action") == JAM_AT - 1
        assert calls[-1][0] == "hold"  # held after the jam, nothing sent since
        deadline = time.monotonic() + 10
        while store.robot_process_of(env_id=JAMMING_ENV_ID).state != "waiting for a learner":
            assert time.monotonic() < deadline
            time.sleep(0.05)


def test_the_robots_process_serves_runs_of_another_image_size_and_the_learner_never_makes_the_env(
    dot_reach: tuple[Settings, Store, int], arm_log: Path
) -> None:
    settings, store, goal_set_id = dot_reach
    with robot_serving(store, ENV_ID, settings.checkpoint_dir):  # (made at the default 48 px)
        for image_size in (16, 24):
            config = real_time_config(env_id=ENV_ID, image_size=image_size, total_steps=120, reset_every_episode=False)
            run_id = create_run(store, goal_set_id, config)
            assert learn_once_beside(settings, presser(store, run_id)) == 0
            run = store.get_run(run_id=run_id)
            assert run.status == RunStatus.FINISHED and run.step == 120, run.status_reason
    opened = [pid for what, _, pid in recorded_by(arm_log) if what == "open"]
    movers = {pid for what, _, pid in recorded_by(arm_log) if what in ("action", "reset", "hold")}
    assert len(movers) == 1 and set(opened) <= movers  # one process; the learner (this one's threads aside) none


def test_a_second_run_of_the_robot_waits_for_it_while_the_first_is_driven_and_then_gets_it(
    dot_reach: tuple[Settings, Store, int], arm_log: Path
) -> None:
    from learner.worker import work  # noqa: PLC0415 - the learner's tests only

    settings, store, goal_set_id = dot_reach
    config = real_time_config(env_id=ENV_ID, total_steps=150, reset_every_episode=False)
    with robot_serving(store, ENV_ID, settings.checkpoint_dir):
        first = create_run(store, goal_set_id, config)
        second = create_run(store, goal_set_id, config)
        other = threading.Thread(target=work, args=(settings,), kwargs={"worker_name": "second", "once": True})
        other.start()  # (it takes one run; the learner below the other)
        try:
            assert learn_once_beside(settings, lambda stop: stop.wait()) == 0
        finally:
            other.join(timeout=300)
        runs = [store.get_run(run_id=run_id) for run_id in (first, second)]
        assert [run.status for run in runs] == [RunStatus.FINISHED] * 2, [run.status_reason for run in runs]
        waited = [run for run in runs if any("waiting for" in event.message for event in store.events(run_id=run.id))]
        assert len(waited) == 1  # the later of the two, told which run had the robot
        driven = {run.id for run in runs} - {waited[0].id}
        message = next(event.message for event in store.events(run_id=waited[0].id) if "waiting for" in event.message)
        assert message.endswith(f"driving run {driven.pop()}"), message
