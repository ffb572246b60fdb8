"""The person's order before an episode on a robot: the arm goes to its start pose first, the reset card then asks
the person to reset the scene, and Ready starts the episode. Stop then Resume while the card waits returns the actor
to waiting for the reset, and the API (which the page reads) says so."""

import sqlite3
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from conftest import create_run
from fastapi.testclient import TestClient
from recording_arm import ENV_ID, LOG_VARIABLE, recorded
from test_actor import real_time_config

from contract.actor_messages import ActorSettings
from contract.settings import get_settings
from contract.store import Store
from learner.actor_handle import ActorProcess
from learner.testing_envs import add_dot_goals
from robot.drive.actor import ActorState

HZ = 10.0


@contextmanager
def actor_of_a_run(
    store: Store, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, episode_steps: int
) -> Iterator[tuple[int, ActorProcess]]:
    """A run on the recording arm (its log tmp_path/arm.log) with a person's reset before every episode, and its
    actor beside this test, which plays the learner: started at step 0."""
    monkeypatch.setenv(LOG_VARIABLE, str(tmp_path / "arm.log"))  # (the actor process inherits both)
    monkeypatch.setenv("RAQ_ENV_MODULES", "learner.testing_envs,recording_arm")
    get_settings.cache_clear()
    config = real_time_config(env_id=ENV_ID, control_hz=HZ, reset_every_episode=True, episode_steps=episode_steps)
    run_id = create_run(store, add_dot_goals(store), config)
    settings = ActorSettings(config.to_dict(), run_id=run_id, database_url=store.url, control_hz=HZ, person_reset=True)
    claim = store.run_claim(run_id=run_id)
    actor = ActorProcess(store, settings, claim=claim, checkpoint_file=str(tmp_path / "run.pt"))
    try:
        actor.start(0, claim)
        yield run_id, actor
    finally:
        actor.close()
        get_settings.cache_clear()


def pump(actor: ActorProcess, seconds: float) -> None:
    """The learner's part for a while: the actor's messages are taken."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        actor.next_message(0.02)


def wait_for(actor: ActorProcess, condition: Callable[[], bool], what: str, seconds: float = 30.0) -> None:
    deadline = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < deadline, f"waited {seconds:g} s for {what}"
        pump(actor, 0.02)


def test_the_arm_goes_home_before_the_person_is_asked_and_stop_resume_returns_to_the_wait(
    store: Store, client: TestClient, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    log = tmp_path / "arm.log"

    def events(what: str, after: float = 0.0) -> list[float]:
        return [at for kind, at in recorded(log) if kind == what and at > after]

    def state() -> str | None:
        """The actor's state as the page reads it (the API)."""
        return client.get(f"/api/runs/{run_id}/robot").json()["actor_state"]

    with actor_of_a_run(store, tmp_path, monkeypatch, episode_steps=1000) as (run_id, actor):
        # the arm to its start pose first, then the card asks the person
        wait_for(actor, lambda: store.robot_status(run_id=run_id).reset_needed, "the reset card")
        assert state() == ActorState.WAITING_FOR_RESET
        asked = time.monotonic()
        homed = events("reset")
        assert len(homed) == 1 and homed[0] < asked and events("action") == []
        # Stop, then Resume, while the card waits: held, then back to waiting for the reset (the arm home again)
        client.post(f"/api/runs/{run_id}/robot/stop").raise_for_status()
        wait_for(actor, lambda: state() == ActorState.STOPPED and bool(events("hold")), "the arm held")
        resumed = time.monotonic()
        client.post(f"/api/runs/{run_id}/robot/resume").raise_for_status()
        wait_for(actor, lambda: state() == ActorState.WAITING_FOR_RESET, "the actor waiting for the reset again", 5.0)
        time.sleep(3 / HZ)  # and it stays so
        assert state() == store.robot_status(run_id=run_id).actor_state == ActorState.WAITING_FOR_RESET
        assert (
            store.robot_status(run_id=run_id).reset_needed
            and client.get(f"/api/runs/{run_id}/robot").json()["reset_needed"]
        )
        time.sleep(3 / HZ)  # the person still resetting: nothing moves
        assert events("action") == []
        homed_again = events("reset", after=resumed)
        # Ready starts the episode: the arm acts, and does not go home again first
        ready = time.monotonic()
        client.post(f"/api/runs/{run_id}/robot/ready").raise_for_status()
        wait_for(actor, lambda: len(events("action")) >= 3, "the episode's actions")
        wait_for(actor, lambda: state() == ActorState.ACTING, "the actor acting")
        assert events("reset", after=ready) == [] and len(homed_again) <= 1
        assert events("action")[0] > ready


def test_a_database_lock_while_the_actor_waits_on_it_between_episodes_does_not_read_as_a_dead_learner(
    store: Store, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The database's writes locked (another connection's exclusive transaction) just as an episode ends: the actor
    waits on the store in its own loop, asking for the reset, as long as the lock lasts, and the learner's
    keep-alives are held up with it. Once it is back, the learner is not taken for dead: the actor lives on, and
    the next Ready starts an episode."""
    log = tmp_path / "arm.log"
    limit = real_time_config().watchdog_seconds

    def actions(after: float = 0.0) -> list[float]:
        return [at for kind, at in recorded(log) if kind == "action" and at > after]

    with actor_of_a_run(store, tmp_path, monkeypatch, episode_steps=5) as (run_id, actor):
        wait_for(actor, lambda: store.robot_status(run_id=run_id).reset_needed, "the reset card")
        store.scene_ready(run_id=run_id)
        wait_for(actor, lambda: bool(actions()), "the episode's first action")
        database = sqlite3.connect(store.url.removeprefix("sqlite:///"), timeout=30)
        try:
            database.execute("BEGIN EXCLUSIVE")  # the episode ends within the lock: its reset waits on it
            pump(actor, 3 * limit)
        finally:
            database.rollback()
            database.close()
        unlocked = time.monotonic()
        pump(actor, limit + 1.0)
        assert actor.process.is_alive(), "the actor took the learner for dead"
        assert store.robot_status(run_id=run_id).actor_state != ActorState.LEARNER_GONE
        wait_for(actor, lambda: store.robot_status(run_id=run_id).reset_needed, "the reset card again")
        store.resume_robot(run_id=run_id)  # (the actor held the arm for the store's silence: its writes waited)

        def ready_when_asked() -> bool:  # (a Resume sends the arm home and asks for the scene again)
            if store.robot_status(run_id=run_id).reset_needed:
                store.scene_ready(run_id=run_id)
            return bool(actions(after=unlocked))

        wait_for(actor, ready_when_asked, "an action after the lock")
