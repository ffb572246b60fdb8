"""Capabilities are the learner's: the web server accepts a run on "cuda" whatever GPUs its own host has (it checks
only that the device is well-formed), a learner claims only runs it can execute (a CPU-only one skips a CUDA run
and takes the next), and a run no learner has taken says what it waits for, in the API and on the runs page."""

from pathlib import Path

import torch
from fastapi.testclient import TestClient
from test_learner_run import create_run, tiny_config

from app.migrate import upgrade
from contract.settings import Settings
from contract.store import RunStatus, Store
from learner.worker import work

ENV = "learner.testing_envs:DotReach-v0"


def test_the_server_queues_a_cuda_run_and_says_it_waits_for_a_learner_with_cuda(client: TestClient) -> None:
    created = client.post("/api/runs", json={"env_id": ENV, "algorithm": "sparse", "config": {"device": "cuda"}})
    assert created.status_code == 201, created.text  # the web host's GPU count is not the run's business
    run = client.get(f"/api/runs/{created.json()['id']}").json()
    assert run["status"] == "queued" and run["config"]["device"] == "cuda"
    assert run["waiting_reason"].startswith("waiting for a learner with CUDA")
    two = client.post("/api/runs", json={"env_id": ENV, "algorithm": "sparse", "config": {"device": "cuda:1"}})
    assert "at least 2 CUDA GPUs (cuda:1)" in two.json()["waiting_reason"]
    cpu = client.post("/api/runs", json={"env_id": ENV, "algorithm": "sparse"}).json()
    assert "CUDA" not in cpu["waiting_reason"]
    listed = {row["id"]: row["waiting_reason"] for row in client.get("/api/runs").json()}  # the runs page's data
    assert listed[run["id"]].startswith("waiting for a learner with CUDA")
    # still refused: a device string that is not one
    bad = client.post("/api/runs", json={"env_id": ENV, "algorithm": "sparse", "config": {"device": "gpu"}})
    assert bad.status_code == 422 and "must be 'cpu', 'cuda' or 'cuda:N'" in bad.text


def test_a_cpu_only_learner_skips_a_cuda_run_and_takes_the_next_one(tmp_path: Path) -> None:
    assert not torch.cuda.is_available()  # this is the CPU-only learner (CI has no GPU)
    url = f"sqlite:///{tmp_path / 'raq.sqlite3'}"
    upgrade(url)
    store = Store(url)
    try:
        settings = Settings(_env_file=None, data_dir=tmp_path, database_url=url)
        on_cuda = create_run(store, None, tiny_config(algorithm="sparse", device="cuda", total_steps=100))
        store.update_run(run_id=on_cuda, priority=5)  # first in the queue
        on_cpu = create_run(store, None, tiny_config(algorithm="sparse", total_steps=100))
        assert work(settings, worker_name="cpu-learner", once=True) == 0
        assert store.get_run(run_id=on_cpu).status == RunStatus.FINISHED
        waiting = store.get_run(run_id=on_cuda)
        assert waiting.status == RunStatus.QUEUED and waiting.worker is None
        assert store.queue_report()[on_cuda].startswith("waiting for a learner with CUDA")
        # nothing more for it: the CUDA run stays for a learner with a GPU, which the store gives it to
        assert store.claim_next_run(worker="cpu-learner") is None
        claimed = store.claim_next_run(worker="gpu-learner", cuda_devices=1)
        assert claimed is not None and claimed.id == on_cuda
    finally:
        store.dispose()
