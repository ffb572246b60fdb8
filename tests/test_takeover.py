"""A take-over: a person drives the arm by hand from the run page (POST /api/runs/{id}/robot/drive while a key is
held), and the robot's own process sends their actions instead of the policy's, through the same pace, limits, hold
and Stop. The API refuses what it must; a take-over's time is the person's; on the recording arm, with real
processes, the person's actions reach the arm at the robot's pace and no faster, stop reaching it within a control
period of the last one sent, and never after a Stop."""

import time
from pathlib import Path

import numpy as np
import pytest
from conftest import robot_subprocess
from fastapi.testclient import TestClient
from gymnasium import spaces
from recording_arm import ENV_ID, recorded_by
from test_actor import HZ, arm_env
from test_stop_means_stop import a_run, arm, calls_after, learner_process, wait_until  # noqa: F401 - a fixture

from app.main import create_app
from contract.actor_messages import spaces_json
from contract.effort import run_effort
from contract.settings import Settings
from contract.store import Store
from contract.store.robots import TAKEOVER_GAP_SECONDS

ARM_HZ = 10.0
"""The recording arm's own control rate."""
PERSON = 0.8765
"""The first number of the person's action: the arm's log tells their actions from the policy's by it."""


def announced(store: Store, run_id: int, dims: int = 2, hz: float = HZ) -> None:
    """The run's actor announced its spaces (as the robot's process does before its first episode)."""
    box = spaces.Box(-1.0, 1.0, (dims,), np.float32)
    store.announce_actor(run_id=run_id, spaces=spaces_json(box, spaces.Box(0, 255, (16, 16, 3), np.uint8), hz))


def _run(store: Store) -> int:
    return store.create_run(env_id=ENV_ID, algorithm="vice_raq", config={}, seed=0, total_steps=100).id


def test_the_api_takes_a_persons_action_and_refuses_a_bad_one_or_one_under_a_stop(
    client: TestClient, store: Store
) -> None:
    run_id = _run(store)
    drive = f"/api/runs/{run_id}/robot/drive"
    before = client.post(drive, json={"action": [0.5, 0.5]})
    assert before.status_code == 409 and "no actor" in before.json()["detail"]  # nothing to drive yet
    announced(store, run_id)
    for bad in ([1.5, 0.0], [0.0, "0.5"], [], [0.0, None]):
        assert client.post(drive, json={"action": bad}).status_code == 422, bad
    for wrong_length in ([0.5], [0.5, 0.5, 0.5]):
        refused = client.post(drive, json={"action": wrong_length})
        assert refused.status_code == 400 and "2 numbers" in refused.json()["detail"]
    assert client.post(drive, json={"action": [0.1, 0.2], "extra": 1}).status_code == 422
    assert store.robot_status(run_id=run_id).takeover_seq == 0  # nothing stored by a refusal
    taken = client.post(drive, json={"action": [0.25, -1]})
    assert taken.status_code == 202
    card = taken.json()
    assert card["takeover_action"] == [0.25, -1.0] and card["action_dims"] == 2 and card["control_hz"] == HZ
    assert store.robot_status(run_id=run_id).takeover_seq == 1
    handed = client.post(f"/api/runs/{run_id}/robot/hand-back")
    assert handed.status_code == 200 and handed.json()["takeover_action"] is None
    client.post(drive, json={"action": [0.25, 0.25]})
    client.post(f"/api/runs/{run_id}/robot/stop")
    assert store.robot_status(run_id=run_id).takeover_action is None  # a Stop ends a take-over
    stopped = client.post(drive, json={"action": [0.25, 0.25]})
    assert stopped.status_code == 409 and "Resume" in stopped.json()["detail"]
    client.post(f"/api/runs/{run_id}/robot/resume")
    assert store.robot_status(run_id=run_id).takeover_action is None  # Resume does not bring it back
    assert client.post("/api/runs/999999/robot/drive", json={"action": [0.0, 0.0]}).status_code == 404


def test_only_a_client_allowed_to_write_drives(make_client, store: Store) -> None:  # type: ignore[no-untyped-def]
    client = make_client(api_token="s3cret-token-for-the-test")
    run_id = _run(store)
    announced(store, run_id)
    drive = f"/api/runs/{run_id}/robot/drive"
    assert client.post(drive, json={"action": [0.0, 0.0]}).status_code == 401
    cross_site = {"Authorization": "Bearer s3cret-token-for-the-test", "Sec-Fetch-Site": "cross-site"}
    assert client.post(drive, json={"action": [0.0, 0.0]}, headers=cross_site).status_code == 403
    allowed = {"Authorization": "Bearer s3cret-token-for-the-test"}
    assert client.post(drive, json={"action": [0.0, 0.0]}, headers=allowed).status_code == 202
    assert store.robot_status(run_id=run_id).takeover_seq == 1


def test_a_takeovers_time_is_the_persons(store: Store) -> None:
    """Actions less than TAKEOVER_GAP_SECONDS apart are one take-over, counted whole in the person's effort."""
    run_id = _run(store)
    announced(store, run_id)
    for _ in range(4):
        store.drive_robot(run_id=run_id, action=[0.0, 0.0])
        time.sleep(0.1)
    time.sleep(TAKEOVER_GAP_SECONDS + 0.2)
    store.drive_robot(run_id=run_id, action=[0.0, 0.0])
    spans = store.takeover_times(run_id=run_id)
    assert len(spans) == 2
    first = (spans[0][1] - spans[0][0]).total_seconds()
    assert 0.25 <= first <= 1.0
    effort = run_effort(store, run_id)
    assert effort.takeovers == 2 and effort.takeover_seconds == pytest.approx(first, abs=0.01)
    assert effort.person_minutes == pytest.approx(effort.takeover_seconds / 60.0, abs=1e-6)


def test_a_persons_actions_reach_the_arm_at_its_pace_end_within_a_period_and_never_after_a_stop(
    arm: tuple[Settings, Store, Path],  # noqa: F811 - the fixture
    tmp_path: Path,
) -> None:
    """The person drives the recording arm (10 Hz) for 3 s, their page sending an action every 0.05 s (half a
    period, as the page does): the arm gets theirs, from the robot's process only, never two within 0.9 of a
    period. Their last one sent, the policy's come back within a period (plus the control thread's poll). A Stop
    pressed while they drive holds the arm: nothing moves until Resume, and after Resume the policy drives (the
    take-over is over). The learner counts the steps they drove."""
    settings, store, log = arm
    run_id = a_run(store, initial_random_steps=50, log_every=20, control_hz=ARM_HZ)
    env = arm_env(settings, log)
    client = TestClient(create_app(Settings(_env_file=None, database_url=store.url, data_dir=settings.data_dir)))
    drive = f"/api/runs/{run_id}/robot/drive"
    period = 1.0 / ARM_HZ

    def sent(after: float) -> list[tuple[float, float, int]]:
        """(when, first number, process) of each action sent after `after`: a "sent" line follows its "action"."""
        entries = recorded_by(log)
        return [
            (at, value, pid)
            for (what, at, pid), (then, value, _) in zip(entries, entries[1:], strict=False)
            if what == "action" and then == "sent" and at > after
        ]

    def by_hand(seconds: float) -> float:
        """Send the person's action every 0.05 s for `seconds`; when the last was sent (monotonic)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            assert client.post(drive, json={"action": [PERSON, -0.5]}).status_code == 202
            last = time.monotonic()
            time.sleep(0.05)
        return last

    with (
        client,
        robot_subprocess(env, ENV_ID, store, tmp_path / "robot.log") as robot,
        learner_process(env, tmp_path / "learner.log"),
    ):
        wait_until(lambda: len(calls_after(log, 0, ("action",))) >= 10, 120, "the arm to move")
        began = time.monotonic()
        last = by_hand(3.0)
        during = [entry for entry in sent(began) if entry[0] <= last]
        mine = [at for at, value, _ in during if value == pytest.approx(PERSON)]
        assert len(mine) >= 0.5 * 3.0 * ARM_HZ  # (its first period or so may still be the policy's; a busy CPU)
        assert {pid for _, _, pid in during} == {robot.pid}
        assert min(np.diff([at for at, _, _ in during])) >= 0.9 * period
        time.sleep(1.0)
        after = [(at, value) for at, value, _ in sent(last)]
        assert after, "the policy drives again"
        last_mine = max((at for at, value in after if value == pytest.approx(PERSON)), default=last)
        assert last_mine - last <= period + 0.5  # (a period from when the control thread saw it; a busy CPU)
        assert any(value != pytest.approx(PERSON) for _, value in after)

        # a Stop while they drive: the arm holds, their further actions are refused, Resume gives it to the policy
        began = time.monotonic()
        by_hand(0.5)
        client.post(f"/api/runs/{run_id}/robot/stop")
        assert client.post(drive, json={"action": [PERSON, -0.5]}).status_code == 409
        wait_until(lambda: store.robot_status(run_id=run_id).actor_state == "stopped", 10, "the Stop honoured")
        stopped = time.monotonic()
        time.sleep(2.0)
        assert calls_after(log, stopped, ("action", "reset")) == []
        client.post(f"/api/runs/{run_id}/robot/resume")
        resumed = time.monotonic()
        wait_until(lambda: len(sent(resumed)) >= 5, 30, "the arm to move after Resume")
        assert all(value != pytest.approx(PERSON) for _, value, _ in sent(resumed))
        wait_until(
            lambda: any(m.value > 0 for m in store.metrics(run_id=run_id, names=["person/steps"])),
            60, "the learner to count the steps driven by hand",
        )  # fmt: skip


def test_the_success_key_and_record_demos_need_an_actor_and_take_what_they_must(
    client: TestClient, store: Store
) -> None:
    run_id = _run(store)
    assert client.post(f"/api/runs/{run_id}/robot/success").status_code == 409
    assert client.post(f"/api/runs/{run_id}/robot/demos", json={"episodes": 2}).status_code == 409
    store.report_actor(run_id=run_id, state="acting")
    marked = client.post(f"/api/runs/{run_id}/robot/success")
    assert marked.status_code == 202 and marked.json()["success_marks"] == 1
    for bad in (0, 21, "2", 2.5, True):
        assert client.post(f"/api/runs/{run_id}/robot/demos", json={"episodes": bad}).status_code == 422, bad
    asked = client.post(f"/api/runs/{run_id}/robot/demos", json={"episodes": 2})
    assert asked.status_code == 202 and asked.json()["demo_pending"] == 2
    again = client.post(f"/api/runs/{run_id}/robot/demos", json={"episodes": 1})
    assert again.status_code == 409 and "2 episodes not begun" in again.json()["detail"]
    assert store.take_demo_episode(run_id=run_id) and store.take_demo_episode(run_id=run_id)
    assert not store.take_demo_episode(run_id=run_id)
    messages = [event.message for event in store.events(run_id=run_id, limit=100_000)]
    assert "a person marked the robot's episode a success" in messages
    assert "record demos: 2 episodes to drive by hand" in messages


def test_a_demo_moves_only_by_hand_and_the_success_key_ends_it_and_teaches_the_classifier(
    arm: tuple[Settings, Store, Path],  # noqa: F811 - the fixture
    tmp_path: Path,
) -> None:
    """Record demos (1 episode) on the recording arm: the arm stands still while no key is held (the policy idle),
    moves with the person's actions only, and the success key ends the episode (the arm goes home: a reset) and
    gives the classifier that episode's last frames. Then the policy acts again."""
    settings, store, log = arm
    run_id = a_run(store, initial_random_steps=50, control_hz=ARM_HZ, episode_steps=200)
    env = arm_env(settings, log)
    client = TestClient(create_app(Settings(_env_file=None, database_url=store.url, data_dir=settings.data_dir)))
    with (
        client,
        robot_subprocess(env, ENV_ID, store, tmp_path / "robot.log"),
        learner_process(env, tmp_path / "learner.log"),
    ):
        wait_until(lambda: len(calls_after(log, 0, ("action",))) >= 5, 120, "the arm to move")
        assert client.post(f"/api/runs/{run_id}/robot/demos", json={"episodes": 1}).status_code == 202
        wait_until(
            lambda: (store.robot_status(run_id=run_id).actor_state or "").startswith("demo"), 60,
            "the demo episode to begin (after the episode under way)",
        )  # fmt: skip
        waiting = time.monotonic()
        time.sleep(1.5)
        assert calls_after(log, waiting, ("action",)) == []  # nobody holds a key: the arm stands still
        driving = time.monotonic()
        end = driving + 1.5
        while time.monotonic() < end:
            client.post(f"/api/runs/{run_id}/robot/drive", json={"action": [PERSON, 0.0]})
            time.sleep(0.05)
        client.post(f"/api/runs/{run_id}/robot/hand-back")
        moved = [value for what, value, _ in recorded_by(log) if what == "sent"]
        assert moved[-10:] == [pytest.approx(PERSON)] * 10
        marked = time.monotonic()
        assert client.post(f"/api/runs/{run_id}/robot/success").status_code == 202
        wait_until(lambda: calls_after(log, marked, ("reset",)), 10, "the demo to end (the arm home)")
        wait_until(lambda: calls_after(log, marked, ("action",)), 30, "the policy to act again")
        wait_until(
            lambda: any("marked a success" in e.message and "positives" in e.message
                        for e in store.events(run_id=run_id, limit=100_000)),
            30, "the learner to take the episode's last frames as positives",
        )  # fmt: skip
