"""A database that blinks is waited out: a real PostgreSQL restarted three times during a run, and a SQLite file
whose disk fills and empties twice. The learner (`raq learn`) never exits before its run is done, the run
finishes, every answer the server acknowledged is kept, and the server answers 503 (never another 5xx) while the
database is away."""

import os
import re
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest
from conftest import ROOT, mounted_tmpfs, run_live_server
from pg_server import PostgresServer

from app.migrate import upgrade
from contract.config import TrainConfig
from contract.store import RunStatus, Store
from learner.testing_envs import add_dot_goals

CONFIG = TrainConfig(
    env_id="learner.testing_envs:DotReach-v0", algorithm="vice_raq", image_size=16, conv_filters=4, hidden_dim=32,
    batch_size=16, classifier_batch_size=8, total_steps=500, episode_steps=25, initial_random_steps=50,
    epoch_steps=50, classifier_steps=2, query_every=50, query_budget=25, eval_every=500, eval_episodes=2,
    checkpoint_every=500, log_every=50, display_size=32, rollout_size=16, replay_capacity=2000, heartbeat_seconds=0.2,
    query_candidates=4,
)  # fmt: skip


class Labeller(threading.Thread):
    """A person at the queue page, through the REST API: answers every pending question of the run (its ground
    truth), polls the run and /health, and keeps every status code and every answer the server acknowledged."""

    def __init__(self, url: str, run_id: int) -> None:
        super().__init__(daemon=True)
        self.url, self.run_id = url, run_id
        self.statuses: list[int] = []
        self.acknowledged: dict[int, bool] = {}
        self.health_503 = 0
        self.done = threading.Event()

    def call(self, client: httpx.Client, method: str, path: str, **kwargs: object) -> httpx.Response | None:
        try:
            response = client.request(method, path, **kwargs)  # type: ignore[arg-type]
        except httpx.TransportError:  # the server's own socket is never down; a slow answer is retried
            return None
        self.statuses.append(response.status_code)
        return response

    def run(self) -> None:
        with httpx.Client(base_url=self.url, timeout=30) as client:
            while not self.done.is_set():
                pending = self.call(client, "GET", "/api/queries", params={"run_id": self.run_id, "status": "pending"})
                for query in pending.json() if pending is not None and pending.status_code == 200 else []:
                    answer = bool(query["ground_truth_success"])
                    posted = self.call(client, "POST", f"/api/queries/{query['id']}/answer", json={"success": answer})
                    if posted is not None and posted.status_code == 200:
                        self.acknowledged[query["id"]] = answer
                self.call(client, "GET", f"/api/runs/{self.run_id}")
                health = self.call(client, "GET", "/health")
                self.health_503 += health is not None and health.status_code == 503
                time.sleep(0.05)


Blink = Callable[[Callable[[], None]], None]
"""Takes the database away, calls the probe while it is away, and brings it back."""


def run_through_blinks(database_url: str, tmp_path: Path, blink: Blink, blinks: int) -> None:
    upgrade(database_url)
    store = Store(database_url)
    goal_set_id = add_dot_goals(store)
    run = store.create_run(
        env_id=CONFIG.env_id, algorithm=CONFIG.algorithm, config=CONFIG.to_dict(), seed=0, goal_set_id=goal_set_id,
        total_steps=CONFIG.total_steps,
    )  # fmt: skip
    data_dir = tmp_path / "learner"  # checkpoints off the database's disk
    env = {key: value for key, value in os.environ.items() if not key.startswith("RAQ_")}
    env.update(
        RAQ_DATABASE_URL=database_url, RAQ_DATA_DIR=str(data_dir), RAQ_ENV_MODULES="learner.testing_envs",
        OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1",
    )  # fmt: skip
    log_path = tmp_path / "learner.log"
    with (
        run_live_server(database_url, tmp_path, {"RAQ_ENV_MODULES": "learner.testing_envs"}) as server,
        log_path.open("w") as log,
    ):
        learner = subprocess.Popen(
            [sys.executable, "-m", "cli", "learn", "--once", "--name", "patient"], cwd=ROOT, env=env, stdout=log,
            stderr=subprocess.STDOUT,
        )  # fmt: skip
        labeller = Labeller(server.url, run.id)
        labeller.start()
        try:
            blinked_at: list[int] = []
            for index in range(blinks):
                wait_until(lambda i=index: step_of(store, run.id) >= 100 + 125 * i, learner, log_path)
                blink(lambda: expect_unavailable(server.url, run.id))
                blinked_at.append(step_of(store, run.id))
            wait_until(lambda: status_of(store, run.id) not in RunStatus.ACTIVE, learner, log_path, finished=True)
            assert learner.wait(timeout=60) == 0, log_path.read_text()[-4000:]
        finally:
            labeller.done.set()
            labeller.join(timeout=60)
            if learner.poll() is None:
                learner.kill()
    final = store.get_run(run_id=run.id)
    assert final.status == RunStatus.FINISHED and final.step == CONFIG.total_steps, final.status_reason
    assert all(step < CONFIG.total_steps for step in blinked_at), blinked_at  # every blink came mid-run
    assert "the database is away" in log_path.read_text()  # the learner did meet the outages
    assert labeller.acknowledged, "no question was answered"
    for query_id, answer in labeller.acknowledged.items():  # every acknowledged answer is kept, as given
        query = store.get_query(query_id=query_id)
        assert query.status == "answered" and query.answer == answer
    assert {status for status in labeller.statuses if status >= 500} <= {503}, sorted(set(labeller.statuses))
    assert all(r.status not in (*RunStatus.ACTIVE, RunStatus.FAILED) for r in store.list_runs())
    store.dispose()


def expect_unavailable(url: str, run_id: int) -> None:
    """While the database is away: writes are JSON 503s with Retry-After (on a full disk, once SQLite needs a new
    page: within a few tries), and /health says so."""
    with httpx.Client(base_url=url, timeout=30) as client:
        deadline = time.monotonic() + 10
        while (write := client.patch(f"/api/runs/{run_id}", json={"priority": 1})).status_code == 200:
            assert time.monotonic() < deadline, "every write succeeded while the database was away"
            time.sleep(0.1)
        assert write.status_code == 503 and write.headers["retry-after"] == "5", write.text
        assert "the database is unreachable" in write.json()["detail"]
        health = client.get("/health")
        assert health.status_code == 503 and health.json()["status"] == "error", health.text


def step_of(store: Store, run_id: int) -> int:
    try:
        return int(store.get_run(run_id=run_id).step or 0)
    except Exception:  # noqa: BLE001 - the database may be away at this moment
        return -1


def status_of(store: Store, run_id: int) -> str:
    try:
        return store.get_run(run_id=run_id).status
    except Exception:  # noqa: BLE001 - the database may be away at this moment
        return RunStatus.TRAINING


def wait_until(
    condition: Callable[[], bool], learner: subprocess.Popen, log_path: Path, *, finished: bool = False,
    timeout: float = 400.0,
) -> None:  # fmt: skip
    deadline = time.monotonic() + timeout
    while not condition():
        if not finished:
            assert learner.poll() is None, f"the learner exited: {log_path.read_text()[-4000:]}"
        assert time.monotonic() < deadline, f"timed out: {log_path.read_text()[-4000:]}"
        time.sleep(0.1)


@pytest.fixture
def postgres() -> Iterator[PostgresServer]:
    with PostgresServer.started() as server:
        yield server


@pytest.mark.slow
def test_a_run_goes_on_through_three_postgresql_restarts(postgres: PostgresServer, tmp_path: Path) -> None:
    def restart(probe: Callable[[], None]) -> None:
        postgres.stop()
        try:
            probe()
        finally:
            postgres.start()

    run_through_blinks(postgres.url, tmp_path, restart, blinks=3)


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    """A 64 MiB tmpfs of this test's own."""
    with mounted_tmpfs(tmp_path / "disk", "64m") as mount:
        yield mount


def fill_then_empty(disk: Path, probe: Callable[[], None], seconds: float = 2.5) -> None:
    """Fill the disk to its last byte, probe the server and keep it full for a while, then empty it."""
    filler = disk / "filler"
    with filler.open("wb", buffering=0) as file:
        for size in (1 << 20, 1 << 16, 1 << 12, 1 << 9):
            try:
                while True:
                    file.write(b"\0" * size)
            except OSError:
                pass
    try:
        probe()
        time.sleep(seconds)
    finally:
        filler.unlink()


@pytest.mark.slow
def test_a_run_goes_on_while_the_sqlite_disk_fills_and_empties(small_disk: Path, tmp_path: Path) -> None:
    url = f"sqlite:///{small_disk / 'raq.sqlite3'}"
    run_through_blinks(url, tmp_path, lambda probe: fill_then_empty(small_disk, probe), blinks=2)
    assert shutil.disk_usage(small_disk).free > 0


TOKEN = "outage-token"


def every_operation(url: str) -> list[tuple[str, str]]:
    """(method, path) of every operation in the server's OpenAPI spec, each id in a path as 1."""
    spec = httpx.get(f"{url}/openapi.json", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30).json()
    return [
        (method.upper(), re.sub(r"\{[^}]+\}", "1", path))
        for path, operations in spec["paths"].items()
        for method in operations
    ]


def test_every_route_is_a_json_503_while_postgresql_is_stopped_token_set_or_not(
    postgres: PostgresServer, tmp_path: Path
) -> None:
    """With PostgreSQL stopped, every operation of the API and every page answers a JSON 503 with Retry-After
    (or a 4xx it decides without the database, or a 200 that needs none), with the bearer token, a login
    cookie, a wrong token or no token at all, and the server logs no traceback."""
    upgrade(postgres.url)
    env = {"RAQ_ENV_MODULES": "learner.testing_envs"}
    (tmp_path / "open").mkdir()
    (tmp_path / "guarded").mkdir()
    with (
        run_live_server(postgres.url, tmp_path / "open", env) as open_server,
        run_live_server(postgres.url, tmp_path / "guarded", {**env, "RAQ_API_TOKEN": TOKEN}) as guarded,
    ):
        operations = every_operation(guarded.url)
        assert len(operations) > 30 and ("PATCH", "/api/runs/1") in operations
        callers = [
            (open_server.url, {}),
            (guarded.url, {"Authorization": f"Bearer {TOKEN}"}),
            (guarded.url, {"Authorization": "Bearer a-wrong-token"}),
            (guarded.url, {"Cookie": "raq_session=a-session-secret"}),
        ]
        postgres.stop()
        try:
            unavailable: dict[tuple[str, str, str], int] = {}
            for base, headers in callers:
                with httpx.Client(base_url=base, headers=headers, timeout=30) as client:
                    for method, path in [*operations, ("GET", "/"), ("GET", "/queue"), ("GET", "/runs/1")]:
                        body = {"json": {}} if method in ("POST", "PATCH", "PUT") else {}
                        response = client.request(method, path, **body)  # type: ignore[arg-type]
                        where = f"{method} {path} with {headers or 'no token'}: {response.status_code}"
                        assert response.status_code < 500 or response.status_code == 503, where + response.text
                        if response.status_code == 503:
                            assert response.headers["retry-after"] == "5", where
                            said = response.json()  # /health's own report, or the routes' detail
                            assert said.get("status") == "error" or "unreachable" in said["detail"], (
                                where + response.text
                            )
                        unavailable[(base, method, path)] = response.status_code
            assert unavailable[(open_server.url, "PATCH", "/api/runs/1")] == 503
            assert unavailable[(open_server.url, "GET", "/")] == 503
            # with the token set, every route but the public ones meets the database before anything else
            guarded_codes = {code for (base, _m, _p), code in unavailable.items() if base == guarded.url}
            assert guarded_codes == {503}, guarded_codes
        finally:
            postgres.start()
        for server in (open_server, guarded):
            assert "Traceback" not in server.log_path.read_text(), server.log_path.read_text()[-3000:]
            back = httpx.get(f"{server.url}/api/runs", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30)
            assert back.status_code == 200, back.text  # the database is back: so is every route
