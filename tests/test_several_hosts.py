"""Learners on several hosts, run for real on loopback: a PostgreSQL server and an S3 API server (moto's
server) started here on 127.0.0.1, learner processes with separate data dirs, checkpoints in the bucket.

- checkpoints at an s3:// URL: written and read streamed, atomic (a writer killed mid-upload leaves the old one);
- staleness by the database's clock: a host whose clock is skewed neither steals a live run nor keeps a dead one;
- two learners on "two hosts": one is SIGKILLed after its checkpoint, the other resumes at that step from the
  bucket, re-reads the answers given since, and the run is never held by both.
"""

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
import torch
from conftest import answer_at_once, free_port
from sqlalchemy import text
from test_learner_run import tiny_config

import contract.store.runs as store_module
from app.migrate import upgrade
from contract.settings import Settings
from contract.store import RunStatus, Store
from learner.checkpoint import checkpoint_url, load_checkpoint, save_checkpoint
from learner.testing_envs import add_dot_goals

ROOT = Path(__file__).resolve().parent.parent
BUCKET = "raq-checkpoints"


# ---------------------------------------------------------------- servers
@pytest.fixture(scope="module")
def s3_env(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, str]]:
    """moto's S3 API server on 127.0.0.1 with a bucket; the standard AWS variables that point at it (also set in
    this process for the duration of the module)."""
    port = free_port()
    log_path = tmp_path_factory.mktemp("moto") / "moto.log"
    env = {
        "AWS_ACCESS_KEY_ID": "testing", "AWS_SECRET_ACCESS_KEY": "testing", "AWS_DEFAULT_REGION": "us-east-1",
        "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}", "NO_PROXY": "127.0.0.1",
    }  # fmt: skip
    with log_path.open("wb") as log:
        server = subprocess.Popen(
            [sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
            stdout=log, stderr=subprocess.STDOUT,
        )  # fmt: skip
    saved = {key: os.environ.get(key) for key in env}
    try:
        deadline = time.monotonic() + 60
        while True:
            assert server.poll() is None, log_path.read_text()
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert time.monotonic() < deadline, "moto's server did not start"
                time.sleep(0.1)
        os.environ.update(env)
        import s3fs

        s3fs.S3FileSystem.clear_instance_cache()
        s3fs.S3FileSystem().mkdir(BUCKET)
        yield env
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        server.terminate()
        server.wait(timeout=10)


# ---------------------------------------------------------------- checkpoints in the bucket
def _state(megabytes: int, marker: int) -> dict:
    return {
        "version": 1, "step": marker, "nested": {"list": [1, 2.5, "x"], "flag": True},
        "replay": {"obs": torch.full((megabytes, 1024, 1024), marker % 251, dtype=torch.uint8)},
    }  # fmt: skip


def test_checkpoints_round_trip_through_s3(s3_env: dict[str, str]) -> None:
    url = checkpoint_url(f"s3://{BUCKET}/round-trip", 7)
    assert url == f"s3://{BUCKET}/round-trip/run-7/checkpoint.pt"
    assert load_checkpoint(url) is None
    state = _state(40, 3)  # 40 MB: a multipart upload of 16 MiB parts
    size = save_checkpoint(url, state)
    assert size > 40 * 2**20
    loaded = load_checkpoint(url)
    assert loaded is not None and loaded["step"] == 3 and loaded["nested"] == state["nested"]
    assert torch.equal(loaded["replay"]["obs"], state["replay"]["obs"])
    with pytest.raises(Exception, match="pickle|Can't|local object"):
        save_checkpoint(url, {"step": 4, "bad": lambda: None})  # a save that fails leaves the old one
    assert load_checkpoint(url)["step"] == 3


_WRITER = """
import sys, torch
from learner.checkpoint import save_checkpoint
save_checkpoint(sys.argv[1], {"step": 2, "replay": {"obs": torch.full((300, 1024, 1024), 2, dtype=torch.uint8)}})
"""


def test_a_writer_killed_mid_upload_leaves_the_old_checkpoint(s3_env: dict[str, str]) -> None:
    import boto3

    url = checkpoint_url(f"s3://{BUCKET}/killed", 1)
    save_checkpoint(url, _state(1, 1))
    writer = subprocess.Popen([sys.executable, "-c", _WRITER, url], cwd=ROOT, env=dict(os.environ, **s3_env))
    client = boto3.client("s3", endpoint_url=s3_env["AWS_ENDPOINT_URL"])
    deadline = time.monotonic() + 120
    while not client.list_multipart_uploads(Bucket=BUCKET).get("Uploads"):  # parts are on their way
        assert writer.poll() is None, "the writer ended before its upload was seen"
        assert time.monotonic() < deadline
        time.sleep(0.05)
    assert load_checkpoint(url)["step"] == 1  # mid-upload, readers see the old checkpoint
    writer.send_signal(signal.SIGKILL)
    writer.wait(timeout=30)
    state = load_checkpoint(url)
    assert state is not None and state["step"] == 1 and state["replay"]["obs"].shape == (1, 1024, 1024)


# ---------------------------------------------------------------- staleness by the database's clock
def _skewed(hours: float) -> Callable[[], datetime]:
    return lambda: datetime.now(UTC) + timedelta(hours=hours)


@pytest.mark.parametrize("backend", ["sqlite", "postgresql"])
def test_a_host_with_a_skewed_clock_does_not_steal_a_live_run(
    backend: str, request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch
) -> None:
    url = request.getfixturevalue("database_url" if backend == "sqlite" else "fresh_postgres")
    store = Store(url)
    run_id = store.create_run(env_id="VisualPusher-v0", algorithm="sparse", config={}).id
    monkeypatch.setattr(store_module, "utcnow", _skewed(-1))  # the live learner's host is an hour behind
    assert store.claim_next_run(worker="live").id == run_id
    assert store.heartbeat(run_id=run_id, worker="live", step=5)
    with store.reading() as session:
        database_now = session.execute(text("SELECT CURRENT_TIMESTAMP")).scalar_one()
    database_now = database_now if isinstance(database_now, datetime) else datetime.fromisoformat(database_now)
    beat = store.get_run(run_id=run_id).heartbeat_at
    assert abs((beat - database_now.replace(tzinfo=UTC)).total_seconds()) < 5  # the database's time, not the host's
    monkeypatch.setattr(store_module, "utcnow", _skewed(+1))  # the other host is an hour ahead
    assert store.claim_next_run(worker="skewed", stale_after_seconds=60) is None
    assert store.get_run(run_id=run_id).worker == "live"
    monkeypatch.setattr(store_module, "utcnow", _skewed(-1))  # behind: a dead learner's run still goes stale
    time.sleep(1.2)
    taken = store.claim_next_run(worker="other", stale_after_seconds=1.0)
    assert taken is not None and taken.id == run_id and taken.worker == "other"
    assert not store.heartbeat(run_id=run_id, worker="live")
    store.dispose()


# ---------------------------------------------------------------- two learners, two data dirs, one bucket


def _learner(
    name: str, data_dir: Path, database_url: str, s3_env: dict[str, str], stale: float, once: bool
) -> subprocess.Popen:
    env = {key: value for key, value in os.environ.items() if not key.startswith("RAQ_")}
    env.update(s3_env)
    env.update(
        RAQ_DATABASE_URL=database_url, RAQ_DATA_DIR=str(data_dir), RAQ_CHECKPOINT_URL=f"s3://{BUCKET}/learners",
        RAQ_STALE_HEARTBEAT_SECONDS=str(stale), RAQ_ENV_MODULES="learner.testing_envs", OMP_NUM_THREADS="1",
    )  # fmt: skip
    data_dir.mkdir(parents=True, exist_ok=True)
    log = (data_dir / "learner.log").open("wb")
    command = [sys.executable, "-m", "learner.worker", "--name", name, "--poll", "0.2", *(["--once"] if once else [])]
    return subprocess.Popen(command, cwd=data_dir, env={**env, "PYTHONPATH": str(ROOT)}, stdout=log, stderr=log)


def _until(condition: Callable[[], bool], what: str, processes: list[subprocess.Popen], timeout: float = 60) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        for process in processes:
            assert process.poll() is None, f"a learner exited early while waiting for {what}"
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


@pytest.mark.slow
def test_a_learner_on_another_host_resumes_a_killed_learners_run_from_s3(
    fresh_postgres: str, s3_env: dict[str, str], tmp_path: Path
) -> None:
    store = Store(fresh_postgres)
    config = tiny_config(algorithm="vice_raq", total_steps=600, checkpoint_every=300, eval_every=600)
    run_id = store.create_run(
        env_id=config.env_id, algorithm=config.algorithm, config=config.to_dict(), seed=config.seed,
        goal_set_id=add_dot_goals(store), total_steps=config.total_steps,
    ).id  # fmt: skip
    messages = lambda: [event.message for event in store.events(run_id=run_id, limit=1000)]  # noqa: E731
    first = _learner("host-a", tmp_path / "host-a", fresh_postgres, s3_env, stale=3.0, once=True)
    second = None
    try:
        # host-b starts once host-a beats from its loop (between a claim and the first beat, setting up can take
        # longer than this test's 3 s staleness on a loaded machine; the default is 60 s)
        _until(lambda: store.get_run(run_id=run_id).status == RunStatus.TRAINING, "host-a training", [first])
        assert store.get_run(run_id=run_id).worker == "host-a"
        second = _learner("host-b", tmp_path / "host-b", fresh_postgres, s3_env, stale=3.0, once=False)  # polls
        _until(lambda: "checkpoint written at step 300 " in " ".join(messages()), "the checkpoint", [first, second])
        pending = store.pending_queries(run_id=run_id)
        assert pending
        yes = 0
        for i, query in enumerate(pending):
            store.answer_query(query_id=query.id, success=i % 2 == 0, labeler="test")
            yes += i % 2 == 0
        used = lambda: all(store.get_query(query_id=q.id).used_at is not None for q in pending)  # noqa: E731
        _until(used, "host-a to read the answers", [first, second])
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=30)
        location = checkpoint_url(f"s3://{BUCKET}/learners", run_id)
        state = load_checkpoint(location)
        assert state is not None and state["step"] == 300  # killed after reading the answers, before checkpointing
        assert len(state["reward_model"]["answered_positives"]) == 0
        assert store.get_run(run_id=run_id).worker == "host-a"  # host-b has not touched it while host-a beat
        finished = lambda: store.get_run(run_id=run_id).status in (RunStatus.FINISHED, RunStatus.FAILED)  # noqa: E731
        _until(finished, "host-b to finish the run", [second], timeout=120)
        second.send_signal(signal.SIGTERM)  # it was polling for more runs
        assert second.wait(timeout=60) == 0, (tmp_path / "host-b" / "learner.log").read_text()[-3000:]
    finally:
        for process in (first, second):
            if process is not None and process.poll() is None:
                process.kill()
                process.wait()
    run = store.get_run(run_id=run_id)
    assert run.status == RunStatus.FINISHED and run.step == config.total_steps and run.worker == "host-b"
    log = messages()
    claims = [m for m in reversed(log) if m.startswith("claimed by")]
    assert claims == ["claimed by host-a", "claimed by host-b (its last learner stopped beating)"]  # once each
    assert any(m.startswith("resumed from checkpoint at step 300; ") for m in log), log
    final = load_checkpoint(location)
    assert final is not None and final["step"] == config.total_steps
    assert len(final["reward_model"]["answered_positives"]) == yes  # no answer lost, none counted twice
    for host in ("host-a", "host-b"):
        assert not (tmp_path / host / "checkpoints").exists()  # the checkpoints live in the bucket only
    seen: set[tuple[str, int]] = set()
    for metric in store.metrics(run_id=run_id):
        assert (metric.name, metric.step) not in seen, f"{metric.name} recorded twice at step {metric.step}"
        seen.add((metric.name, metric.step))
    store.dispose()


def test_labellers_answering_different_queries_at_once_on_postgresql_all_succeed(fresh_postgres: str) -> None:
    """Many answers at once (as bench/load.py's 50 clients give them) all land, numbered in commit order."""
    store = Store(fresh_postgres)
    run_id = store.create_run(env_id="VisualPusher-v0", algorithm="sparse", config={}).id
    png = b"\x89PNG\r\n\x1a\nquery"
    ids = [
        store.post_query(run_id=run_id, env_step=i, model_png=png, display_png=png, score=0.0).id for i in range(120)
    ]
    assert answer_at_once(store, ids, 12) == []
    answers = store.new_answers(run_id=run_id, since_seq=0)
    assert [a.answer_seq for a in answers] == list(range(1, 121))
    assert sorted(a.query_id for a in answers) == ids
    store.dispose()


def test_the_policy_export_and_run_deletion_reach_checkpoints_in_s3(s3_env: dict[str, str], tmp_path: Path) -> None:
    """With RAQ_CHECKPOINT_URL in a bucket, GET /api/runs/{id}/policy streams the policy from there and DELETE
    /api/runs/{id} removes the run's folder there (the server needs no shared file system either)."""
    import s3fs
    from fastapi.testclient import TestClient

    from app.main import create_app

    url = f"sqlite:///{tmp_path / 'raq.sqlite3'}"
    upgrade(url)
    store = Store(url)
    run_id = store.create_run(env_id="VisualPusher-v0", algorithm="sparse", config={}).id
    store.dispose()
    base = f"s3://{BUCKET}/exports"
    save_checkpoint(f"{base}/run-{run_id}/policy.pt", {"marker": torch.arange(5)})
    fs = s3fs.S3FileSystem()
    uploaded = fs.cat(f"{BUCKET}/exports/run-{run_id}/policy.pt")
    settings = Settings(data_dir=tmp_path, database_url=url, checkpoint_url=base)
    with TestClient(create_app(settings)) as client:
        response = client.get(f"/api/runs/{run_id}/policy")
        assert response.status_code == 200 and response.content == uploaded
        assert client.delete(f"/api/runs/{run_id}").status_code == 204
    fs.invalidate_cache()
    assert not fs.exists(f"{BUCKET}/exports/run-{run_id}")
