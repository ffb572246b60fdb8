"""One arm, one driver: an actor moves its robot only while it holds it for its run's current claim. After a
takeover the old actor sends nothing more and lets go; a second run of the same robot waits, saying "robot busy
with run N", and moves it only once the first has let go. Both on the recording arm, each actor with its own log."""

import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from conftest import create_run
from recording_arm import ENV_ID, LOG_VARIABLE, recorded
from sqlalchemy import update
from test_actor import real_time_config

from contract.actor_messages import ActorError, ActorSettings
from contract.config import TrainConfig
from contract.settings import Settings, get_settings
from contract.store import Store
from contract.store.models import Run
from learner.actor_handle import ActorProcess
from robot.drive.actor import ActorState

HZ = 10.0


def start_actor(
    store: Store, run_id: int, log: Path, monkeypatch: pytest.MonkeyPatch, config: TrainConfig, claim: int
) -> ActorProcess:
    """An actor process of the run on the recording arm for a learner holding `claim`, writing to `log` (the
    process inherits it)."""
    monkeypatch.setenv(LOG_VARIABLE, str(log))
    settings = ActorSettings(config.to_dict(), run_id=run_id, database_url=store.url, control_hz=HZ, person_reset=False)
    return ActorProcess(store, settings, claim=claim, checkpoint_file=str(log.with_suffix(".pt")))


def actions(log: Path) -> list[float]:
    return [at for what, at in recorded(log) if what == "action"]


def pump(actors: list[ActorProcess], until: Callable[[], bool], timeout: float = 30.0) -> None:
    """Take the actors' messages (the learners' part) until `until()` or the timeout."""
    deadline = time.monotonic() + timeout
    while not until():
        assert time.monotonic() < deadline, "timed out"
        for actor in actors:
            if actor.process.is_alive():
                try:
                    actor.next_message(0.02)
                except ActorError:  # (it ended meanwhile: what its learner would be told)
                    assert not actor.process.is_alive()


def take_over(store: Store, run_id: int) -> int:
    """Another learner claims the run, its learner's heartbeat being stale: the new claim."""
    with store.writing() as session:
        session.execute(update(Run).where(Run.id == run_id).values(heartbeat_at=store._db_now(120)))
    claimed = store.claim_next_run(worker="second-learner")
    assert claimed is not None and claimed.id == run_id
    return claimed.claim


@pytest.fixture
def arm_env(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setenv("RAQ_ENV_MODULES", "learner.testing_envs,recording_arm")
    get_settings.cache_clear()
    yield
    get_settings.cache_clear()


def test_after_a_takeover_the_old_actor_sends_nothing_and_the_new_one_drives_alone(
    dot_reach: tuple[Settings, Store, int], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, arm_env: None
) -> None:
    """A learner that went quiet while alive keeps its actor; another claims the run. The old actor's next move
    is refused: no action (nor hold) after the takeover but the one under way, it says so and exits. The new
    learner's actor moves the arm only after the old one's last action."""
    _, store, goal_set_id = dot_reach
    config = real_time_config(env_id=ENV_ID, control_hz=HZ, reset_every_episode=False, episode_steps=20)
    run_id = create_run(store, goal_set_id, config)
    first_claim = store.claim_next_run(worker="first-learner").claim
    old_log, new_log = tmp_path / "old.log", tmp_path / "new.log"
    old = start_actor(store, run_id, old_log, monkeypatch, config, first_claim)
    new = None
    try:
        old.start(0, first_claim)
        pump([old], lambda: len(actions(old_log)) >= 10)
        taken_at = time.monotonic()
        second_claim = take_over(store, run_id)
        new = start_actor(store, run_id, new_log, monkeypatch, config, second_claim)
        new.start(0, second_claim)
        pump([old, new], lambda: len(actions(new_log)) >= 10)
        assert not old.process.is_alive()  # it let go and ended
        assert old.process.exitcode == 0
    finally:
        old.close()
        if new is not None:
            new.close()
    old_events = recorded(old_log)
    after = [(what, at) for what, at in old_events if at > taken_at + 1.0 / HZ]
    assert after == [], after  # nothing after the takeover but an action already under way
    assert min(actions(new_log)) > max(actions(old_log))


def test_a_second_run_of_the_robot_waits_while_the_first_drives_it(
    dot_reach: tuple[Settings, Store, int], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, arm_env: None
) -> None:
    """Two runs of one arm on one host: the second's actor says "robot busy with run N" and moves nothing while
    the first acts; once the first is closed (its arm held), the second drives."""
    _, store, goal_set_id = dot_reach
    config = real_time_config(env_id=ENV_ID, control_hz=HZ, reset_every_episode=False, episode_steps=20)
    first_run, second_run = create_run(store, goal_set_id, config), create_run(store, goal_set_id, config)
    first_log, second_log = tmp_path / "first.log", tmp_path / "second.log"
    first = start_actor(store, first_run, first_log, monkeypatch, config, store.run_claim(run_id=first_run))
    second = start_actor(store, second_run, second_log, monkeypatch, config, store.run_claim(run_id=second_run))
    try:
        first.start(0, store.run_claim(run_id=first_run))
        pump([first], lambda: len(actions(first_log)) >= 5)
        second.start(0, store.run_claim(run_id=second_run))
        busy = ActorState.robot_busy(first_run)
        pump([first, second], lambda: store.robot_status(run_id=second_run).actor_state == busy)
        pump([first, second], lambda: len(actions(first_log)) >= 25)
        assert recorded(second_log) == []  # not a reset, not an action, not a hold
        first.close()
        closed_at = time.monotonic()
        pump([second], lambda: len(actions(second_log)) >= 5)
    finally:
        first.close()
        second.close()
    first_events = recorded(first_log)
    assert first_events[-1][0] == "hold" and first_events[-1][1] <= closed_at
    second_events = recorded(second_log)
    assert second_events[0][1] > first_events[-1][1]  # (its first move: the reset to the start pose)
