"""Runs side by side: priorities in the claim order, a lower-priority run yielding to a higher one at its
next checkpoint, why a queued run waits, archive and delete with everything a run owns, answers in the events."""

import threading
import time
from datetime import timedelta
from pathlib import Path

import pytest
from sqlalchemy import func, select, update

from cli import default_learners
from contract.store import Conflict, RunStatus, Store
from contract.store.models import Event, Metric, Query, Run, utcnow


def new_run(store: Store, *, priority: int = 0, total_steps: int = 100) -> int:
    return store.create_run(
        env_id="VisualPusher-v0", algorithm="sparse", config={}, total_steps=total_steps, priority=priority
    ).id


def backdate_queue(store: Store, run_id: int, seconds: float = 60.0) -> None:
    with store.writing() as session:
        session.execute(update(Run).where(Run.id == run_id).values(queued_at=utcnow() - timedelta(seconds=seconds)))


def test_learners_take_the_highest_priority_first_then_the_oldest(store: Store) -> None:
    demo = new_run(store, priority=-10)
    first = new_run(store)
    urgent = new_run(store, priority=5)
    second = new_run(store)
    order = [store.claim_next_run(worker=f"w{i}").id for i in range(4)]
    assert order == [urgent, first, second, demo]
    assert store.claim_next_run(worker="w9") is None


def test_why_a_queued_run_waits(store: Store) -> None:
    busy = new_run(store)
    waiting_a, waiting_b = new_run(store), new_run(store)
    assert store.queue_report()[busy].startswith("waiting for a learner")
    store.claim_next_run(worker="w1")
    store.heartbeat(run_id=busy, worker="w1", status=RunStatus.TRAINING)
    report = store.queue_report()
    assert busy not in report
    assert report[waiting_a] == f"learner busy with #{busy}"
    assert report[waiting_b] == f"learner busy with #{busy}; after #{waiting_a}"


def test_a_higher_priority_run_that_waits_is_found_only_after_it_waited(store: Store) -> None:
    low = new_run(store, priority=-10)
    store.claim_next_run(worker="w1")
    assert store.higher_priority_waiting(run_id=low) is None
    same = new_run(store, priority=-10)
    backdate_queue(store, same)
    assert store.higher_priority_waiting(run_id=low) is None  # equal priority: no yield
    high = new_run(store, priority=0)
    assert store.higher_priority_waiting(run_id=low) is None  # just queued: an idle learner may take it
    backdate_queue(store, high)
    assert store.higher_priority_waiting(run_id=low).id == high


def test_archive_and_delete_a_run_with_everything_it_owns(store: Store, tmp_path: Path) -> None:
    run_id = new_run(store)
    with pytest.raises(Conflict):
        store.update_run(run_id=run_id, archived=True)  # queued: stop it first
    store.claim_next_run(worker="w1")
    query = store.post_query(run_id=run_id, env_step=10, model_png=b"m", display_png=b"d", score=1.0)
    store.answer_query(query_id=query.id, success=True, labeler="ann")
    store.record_metrics(run_id=run_id, step=10, values={"eval/return": 1.0})
    store.record_rollout(run_id=run_id, env_step=10, data=b"gif", frame_count=1)
    with pytest.raises(Conflict):
        store.delete_run(run_id=run_id)  # a learner holds it
    store.set_run_status(run_id=run_id, status=RunStatus.STOPPED, worker="w1")
    assert store.update_run(run_id=run_id, archived=True, priority=3).archived
    assert [run.id for run in store.list_runs(archived=False)] == []
    assert [run.id for run in store.list_runs(archived=True)] == [run_id]
    assert any(event.message == f"query {query.id} answered yes by ann" for event in store.events(run_id=run_id))
    store.delete_run(run_id=run_id)
    with store.reading() as session:
        for model in (Run, Query, Metric, Event):
            column = model.id if model is Run else model.run_id
            assert session.scalar(select(func.count()).select_from(model).where(column == run_id)) == 0


def test_learners_default_to_one_per_two_cores() -> None:
    assert [default_learners(cores) for cores in (1, 2, 3, 8)] == [1, 1, 1, 4]


def test_a_lower_priority_run_yields_at_its_next_checkpoint(tmp_path: Path) -> None:
    """A real learner trains the demo-like low-priority run; a person's run is queued and waits; at the next
    checkpoint the learner queues the low run again, trains the person's run, then resumes the low one."""
    from app.migrate import upgrade
    from contract.settings import Settings
    from learner.worker import work
    from tests.test_learner_run import tiny_config

    url = f"sqlite:///{tmp_path / 'raq.sqlite3'}"
    upgrade(url)
    store = Store(url)
    settings = Settings(data_dir=tmp_path, database_url=url)
    try:
        low_config, high_config = tiny_config(algorithm="sparse", total_steps=800), tiny_config(algorithm="sparse")
        low = store.create_run(
            env_id=low_config.env_id, algorithm="sparse", config=low_config.to_dict(), total_steps=800, priority=-10
        ).id
        interrupt = threading.Event()
        worker = threading.Thread(target=work, args=(settings,), kwargs={"interrupt": interrupt, "poll_seconds": 0.2})
        worker.start()
        try:
            deadline = time.monotonic() + 120
            while store.get_run(run_id=low).step < 50 and time.monotonic() < deadline:
                time.sleep(0.1)
            high = store.create_run(
                env_id=high_config.env_id, algorithm="sparse", config=high_config.to_dict(), total_steps=300
            ).id
            backdate_queue(store, high)
            while time.monotonic() < deadline and not (
                store.get_run(run_id=low).status == store.get_run(run_id=high).status == RunStatus.FINISHED
            ):
                time.sleep(0.2)
        finally:
            interrupt.set()
            worker.join(timeout=60)
        low_run, high_run = store.get_run(run_id=low), store.get_run(run_id=high)
        assert high_run.status == low_run.status == RunStatus.FINISHED
        assert high_run.finished_at < low_run.finished_at
        messages = [event.message for event in reversed(store.events(run_id=low))]
        yielded = [m for m in messages if m.startswith(f"yielded to run #{high} (priority 0) at step ")]
        assert yielded, messages
        assert int(yielded[0].split("at step ")[1].split(":")[0]) % low_config.checkpoint_every == 0
        assert any(m.startswith("resumed from checkpoint") for m in messages)
        # honest progress: an ETA only from the training phase's speed (none during the random warm-up)
        etas = store.metrics(run_id=high, names=["perf/eta_seconds"])
        assert etas and min(m.step for m in etas) >= high_config.initial_random_steps + high_config.log_every
        assert low_run.phase is None and high_run.phase is None  # ended: no phase

        # the trained policy, downloaded through the API, loads with the documented snippet and acts
        from fastapi.testclient import TestClient

        from app.main import create_app
        from contract.envs import make_env
        from learner.policy import load_policy

        with TestClient(create_app(settings)) as client:
            response = client.get(f"/api/runs/{high}/policy")
        assert response.status_code == 200 and "policy.pt" in response.headers["content-disposition"]
        checkpoint_size = (tmp_path / "checkpoints" / f"run-{high}" / "checkpoint.pt").stat().st_size
        assert len(response.content) < checkpoint_size / 2  # the policy alone, not the replay buffer
        (tmp_path / "policy.pt").write_bytes(response.content)
        policy = load_policy(tmp_path / "policy.pt")
        env = make_env(high_config.env_id, image_size=16, display_size=32)
        observation, _info = env.reset(seed=0)
        action = policy.env_action(observation, env)
        assert action.shape == env.action_space.shape and env.action_space.contains(action)
        assert policy.step == 300
    finally:
        store.dispose()
