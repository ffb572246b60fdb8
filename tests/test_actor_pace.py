"""The actor's pace on a robot: no two actions closer than 0.9 of a control period, a late step sent late and never
followed by an early one (no catching up), and `limit_action` told the real time since the previous action."""

from pathlib import Path

import numpy as np
import pytest
from conftest import create_run
from recording_arm import LATE_ENV_ID, LATE_EVERY, LOG_VARIABLE, recorded
from test_actor import real_time_config

from contract.actor_messages import ActorSettings
from contract.settings import Settings, get_settings
from contract.store import Store
from learner.actor_handle import ActorProcess

HZ = 10.0


def test_a_late_step_is_sent_late_and_never_followed_by_an_early_one(
    dot_reach: tuple[Settings, Store, int], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An arm whose every fifth action takes 1.3 periods to send, over three episodes: the action after a late one
    comes a full period after it; every interval is at least 0.9 of a period, across the resets too; each action's
    `limit_action` was told the time since the previous one (one period for an episode's first)."""
    _, store, goal_set_id = dot_reach
    log = tmp_path / "arm.log"
    monkeypatch.setenv(LOG_VARIABLE, str(log))  # (the actor process inherits both)
    monkeypatch.setenv("RAQ_ENV_MODULES", "learner.testing_envs,recording_arm")
    get_settings.cache_clear()
    config = real_time_config(env_id=LATE_ENV_ID, control_hz=HZ, reset_every_episode=False, episode_steps=12)
    run_id = create_run(store, goal_set_id, config)
    settings = ActorSettings(config.to_dict(), run_id=run_id, database_url=store.url, control_hz=HZ, person_reset=False)
    claim = store.run_claim(run_id=run_id)
    actor = ActorProcess(store, settings, claim=claim, checkpoint_file=str(tmp_path / "run.pt"))
    try:
        actor.start(0, claim)
        while sum(what == "action" for what, _ in recorded(log)) < 36:
            actor.next_message(0.1)  # (the learner's part: its steps are taken, its keep-alives sent)
    finally:
        actor.close()
    get_settings.cache_clear()
    events = recorded(log)
    period = 1.0 / HZ
    actions = np.array([at for what, at in events if what == "action"])
    intervals = np.diff(actions)
    late = np.flatnonzero(intervals > 1.2 * period)
    assert len(late) >= 36 // LATE_EVERY - 1, intervals  # the arm was late, and often
    assert intervals.min() >= 0.9 * period, intervals  # and no step came early after it
    assert abs(np.median(intervals) - period) < 0.1 * period, intervals  # on time, the rate is kept
    # a full period after (catching up would send it at the tick, 0.3 of a period early); the log's times carry a
    # few ms of the actor's other threads, which encode and post the late step at that moment
    assert np.all(intervals[late[late + 1 < len(intervals)] + 1] >= 0.95 * period), intervals
    told: list[tuple[float, float | None]] = []  # (what limit_action was told, the real time since the last action)
    previous: float | None = None
    for what, value in events:
        if what == "reset":
            previous = None
        elif what == "limit":
            told.append((value, previous))
        elif what == "action":
            previous = value
    assert len(told) >= len(actions) and sum(what == "reset" for what, _ in events) >= 3
    for index, (seconds, since) in enumerate(told[: len(actions)]):
        expected = period if since is None else actions[index] - since
        assert abs(seconds - expected) < 0.02, (index, seconds, expected)
