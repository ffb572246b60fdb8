"""Shared fixtures: a migrated temporary SQLite database, the app under TestClient, a live uvicorn server."""

import io
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import httpx
import pytest
from fastapi.testclient import TestClient
from pg_server import PostgresServer, free_port
from PIL import Image
from sqlalchemy import create_engine, text

from app.main import create_app
from app.migrate import upgrade
from contract.settings import Settings
from contract.store import Store

if TYPE_CHECKING:
    from playwright.sync_api import Browser, Page

    from contract.config import TrainConfig

ROOT = Path(__file__).resolve().parent.parent
# The tests' own env module, allowed for every learner the tests start (in-process or as a subprocess).
os.environ.setdefault("RAQ_ENV_MODULES", "learner.testing_envs")
ARTIFACTS = ROOT / "test-artifacts"
GPU_TESTS_NOT_RUN: list[str] = []


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Tests marked gpu need CUDA: where there is none they are deselected and named in the summary (CI has no
    GPU; the GPU path's code also runs eagerly on the CPU in tests/test_device_updates.py)."""
    import torch

    if torch.cuda.is_available():
        return
    gpu = [item for item in items if item.get_closest_marker("gpu")]
    if gpu:
        GPU_TESTS_NOT_RUN.extend(item.nodeid for item in gpu)
        config.hook.pytest_deselected(items=gpu)
        items[:] = [item for item in items if not item.get_closest_marker("gpu")]


def pytest_sessionfinish(session: pytest.Session) -> None:
    """On a pytest-xdist worker: hand the GPU tests it deselected to the controller, which prints the summary."""
    workeroutput = getattr(session.config, "workeroutput", None)
    if workeroutput is not None:
        workeroutput["gpu_tests_not_run"] = list(GPU_TESTS_NOT_RUN)


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node: Any, error: object) -> None:
    """On the pytest-xdist controller: the GPU tests each worker deselected (every worker collects them all)."""
    for nodeid in getattr(node, "workeroutput", {}).get("gpu_tests_not_run", []):
        if nodeid not in GPU_TESTS_NOT_RUN:
            GPU_TESTS_NOT_RUN.append(nodeid)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if GPU_TESTS_NOT_RUN:
        terminalreporter.write_sep("=", f"{len(GPU_TESTS_NOT_RUN)} GPU tests NOT RUN: no CUDA device on this machine")
        for nodeid in GPU_TESTS_NOT_RUN:
            terminalreporter.write_line(f"not run (no CUDA): {nodeid}")


@pytest.fixture
def database_url(tmp_path: Path) -> str:
    url = f"sqlite:///{tmp_path / 'raq.sqlite3'}"
    upgrade(url)
    return url


@pytest.fixture(scope="module")
def postgres_url() -> Iterator[str]:
    """A throw-away PostgreSQL server (tests/pg_server.py) that the test module shares: its database `raq`."""
    with PostgresServer.started() as server:
        yield server.url


@pytest.fixture
def fresh_postgres(postgres_url: str) -> Iterator[str]:
    """A new, migrated database on the module's PostgreSQL server, for one test."""
    name = f"raq_{uuid.uuid4().hex[:12]}"
    admin = create_engine(postgres_url, isolation_level="AUTOCOMMIT")
    with admin.connect() as connection:
        connection.execute(text(f"CREATE DATABASE {name}"))
    admin.dispose()
    url = postgres_url.rsplit("/", 1)[0] + f"/{name}"
    upgrade(url)
    yield url


@pytest.fixture
def store(database_url: str) -> Iterator[Store]:
    opened = Store(database_url)
    yield opened
    opened.dispose()


@pytest.fixture
def make_settings(database_url: str, tmp_path: Path) -> Callable[..., Settings]:
    def _make(**overrides: object) -> Settings:
        values: dict[str, object] = {"database_url": database_url, "data_dir": tmp_path, "api_token": None}
        values.update(overrides)
        return Settings(_env_file=None, **values)  # type: ignore[arg-type]

    return _make


@pytest.fixture
def make_client(make_settings: Callable[..., Settings]) -> Iterator[Callable[..., TestClient]]:
    clients: list[TestClient] = []

    def _make(**overrides: object) -> TestClient:
        client = TestClient(create_app(make_settings(**overrides)))
        client.__enter__()
        clients.append(client)
        return client

    yield _make
    for client in clients:
        client.__exit__(None, None, None)


@pytest.fixture
def client(make_client: Callable[..., TestClient]) -> TestClient:
    return make_client()


def image_bytes(
    size: tuple[int, int] = (96, 64), color: tuple[int, int, int] = (200, 40, 40), fmt: str = "PNG"
) -> bytes:
    """A small real image with a marker in one corner (so crops and resizes are visible)."""
    image = Image.new("RGB", size, color)
    for x in range(min(8, size[0])):
        for y in range(min(8, size[1])):
            image.putpixel((x, y), (255, 255, 255))
    buffer = io.BytesIO()
    image.save(buffer, format=fmt)
    return buffer.getvalue()


@pytest.fixture
def make_image() -> Callable[..., bytes]:
    return image_bytes


@pytest.fixture
def goal_set_with_photo(client: TestClient) -> dict:
    goal_set = client.post("/api/goal-sets", json={"name": "puck on target"}).json()
    response = client.post(
        f"/api/goal-sets/{goal_set['id']}/examples", files=[("files", ("goal.png", image_bytes(), "image/png"))]
    )
    assert response.status_code == 201, response.text
    return goal_set


def answer_at_once(
    store: Store, query_ids: list[int], threads: int, *, alongside: Callable[[], None] | None = None
) -> list[str]:
    """Answer the queries from `threads` threads released together (yes for even ids), with `alongside` running
    at the same moment in one more thread; returns the errors the answers raised."""
    barrier, failures = threading.Barrier(threads + (alongside is not None)), []

    def answer(chunk: list[int]) -> None:
        barrier.wait()
        for query_id in chunk:
            try:
                store.answer_query(query_id=query_id, success=query_id % 2 == 0, labeler="at once")
            except Exception as error:  # noqa: BLE001
                failures.append(repr(error))

    def other() -> None:
        barrier.wait()
        assert alongside is not None
        alongside()

    workers = [threading.Thread(target=answer, args=(query_ids[i::threads],)) for i in range(threads)]
    workers += [threading.Thread(target=other)] if alongside is not None else []
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join()
    return failures


@dataclass
class LiveServer:
    url: str
    process: subprocess.Popen
    log_path: Path

    def rss_bytes(self) -> int:
        """The server process's resident memory, from /proc."""
        for line in Path(f"/proc/{self.process.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
        raise RuntimeError("no VmRSS")


@contextmanager
def run_live_server(database_url: str, tmp_path: Path, env_overrides: dict[str, str]) -> Iterator[LiveServer]:
    """`raq serve` as the CLI runs it: uvicorn on app.main:create_app, 127.0.0.1, a free port, this test's DB;
    RAQ_* settings only from env_overrides."""
    port = free_port()
    env = {key: value for key, value in os.environ.items() if not key.startswith("RAQ_")}
    env.update({"RAQ_DATABASE_URL": database_url, "RAQ_DATA_DIR": str(tmp_path), "PYTHONUNBUFFERED": "1"})
    env.update(env_overrides)
    log_path = tmp_path / f"server-{port}.log"
    python_path = os.pathsep.join(filter(None, [str(ROOT), env_overrides.get("PYTHONPATH")]))
    with log_path.open("wb") as log:
        process = subprocess.Popen(
            [sys.executable, "-m", "uvicorn", "--factory", "app.main:create_app",
             "--host", "127.0.0.1", "--port", str(port), "--log-level", "warning", "--no-proxy-headers"],
            cwd=tmp_path, env={**env, "PYTHONPATH": python_path}, stdout=log, stderr=subprocess.STDOUT,
        )  # fmt: skip
        base_url = f"http://127.0.0.1:{port}"
        try:
            deadline = time.monotonic() + 60
            while True:
                if process.poll() is not None:
                    raise RuntimeError(f"the server exited: {log_path.read_text()}")
                try:
                    if httpx.get(f"{base_url}/health", timeout=2).status_code == 200:
                        break
                except httpx.HTTPError:
                    pass
                if time.monotonic() > deadline:
                    raise RuntimeError(f"the server did not answer /health in 60 s: {log_path.read_text()}")
                time.sleep(0.2)
            yield LiveServer(base_url, process, log_path)
        finally:
            process.terminate()
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


@pytest.fixture
def make_live_server(database_url: str, tmp_path: Path) -> Iterator[Callable[..., LiveServer]]:
    """Start live servers with RAQ_* settings of the test's choosing: make_live_server(RAQ_API_TOKEN="…")."""
    with ExitStack() as stack:
        yield lambda **env: stack.enter_context(run_live_server(database_url, tmp_path, env))


@pytest.fixture
def live_server(make_live_server: Callable[..., LiveServer]) -> str:
    """A live server without a token; its base URL."""
    return make_live_server().url


@pytest.fixture
def dot_reach(tmp_path: Path) -> Iterator[tuple[Settings, Store, int]]:
    """A learner's settings, a migrated SQLite store and a goal set of the DotReach test env."""
    from learner.testing_envs import add_dot_goals  # noqa: PLC0415 - the learner's tests only

    url = f"sqlite:///{tmp_path / 'raq.sqlite3'}"
    upgrade(url)
    store = Store(url)
    settings = Settings(data_dir=tmp_path, database_url=url, stale_heartbeat_seconds=60.0)
    yield settings, store, add_dot_goals(store)
    store.dispose()


@contextmanager
def mounted_tmpfs(mount: Path, size: str) -> Iterator[Path]:
    """A tmpfs of `size` (as mount's -o size=, e.g. "64m") at the new folder `mount` (mounted as root, which
    `make test` runs as), unmounted after."""
    mount.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mount)], check=True)
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def create_run(store: Store, goal_set_id: int | None, config: "TrainConfig") -> int:
    """A queued run of `config` (its env, algorithm, seed and steps in the run's columns), as the API makes it."""
    run = store.create_run(
        env_id=config.env_id, algorithm=config.algorithm, config=config.to_dict(), seed=config.seed,
        goal_set_id=goal_set_id, total_steps=config.total_steps,
    )  # fmt: skip
    return run.id


def learn_once_beside(settings: Settings, person: Callable[[threading.Event], None]) -> int:
    """`raq learn --once` in this process while `person(done)` answers (queries, resets) on a thread of its own
    until the learner is done; the learner's exit code."""
    from learner.worker import work  # noqa: PLC0415 - the learner's tests only

    done = threading.Event()
    helper = threading.Thread(target=person, args=(done,), daemon=True)
    helper.start()
    try:
        return work(settings, worker_name="w", once=True)
    finally:
        done.set()
        helper.join()


# ---------------------------------------------------------------- a robot's own process
STANDIN = "robot.standin:PusherStandIn-v0"


@contextmanager
def robot_serving(store: Store, env_id: str, checkpoint_base: Path | str) -> Iterator[None]:
    """The robot's own process (robot/drive/process.py) on a thread of this process, up once its row is in the
    store; stopped (the arm held) at the end."""
    from learner.acting import SAC_ACTING  # noqa: PLC0415 - the robot tests only
    from robot.drive.process import serve_robot  # noqa: PLC0415

    stop = threading.Event()
    ended: list[str] = []
    thread = threading.Thread(
        target=lambda: ended.append(serve_robot(
            store, env_id=env_id, checkpoint_base=str(checkpoint_base), acting=SAC_ACTING, stop=stop
        )),
        name=f"robot {env_id}", daemon=True,
    )  # fmt: skip
    thread.start()
    try:
        deadline = time.monotonic() + 60
        while (process := store.robot_process_of(env_id=env_id)) is None or process.state != "waiting for a learner":
            assert thread.is_alive() and time.monotonic() < deadline, f"the robot process of {env_id} did not come up"
            time.sleep(0.05)
        yield
    finally:
        stop.set()
        thread.join(timeout=30)
    assert ended == ["stopped"], ended


@contextmanager
def robot_subprocess(env: dict[str, str], env_id: str, store: Store, log: Path) -> Iterator[subprocess.Popen]:
    """`raq robot ENV_ID` in a process of its own with `env` (its output in `log`), up once its row is in the store
    and it waits for a learner; interrupted (the arm held) at the end."""
    with log.open("wb") as output:
        process = subprocess.Popen(
            [sys.executable, "-m", "cli", "robot", env_id],
            cwd=ROOT,
            env=env,
            stdout=output,
            stderr=subprocess.STDOUT,
            process_group=0,  # (paused by a test, it stays paused whatever the processes beside it do)
        )
        try:
            deadline = time.monotonic() + 120
            while (row := store.robot_process_of(env_id=env_id)) is None or row.state != "waiting for a learner":
                assert process.poll() is None, log.read_text()
                assert time.monotonic() < deadline, f"the robot process did not come up: {log.read_text()}"
                time.sleep(0.1)
            yield process
        finally:
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


# ---------------------------------------------------------------- the browser tests' Chromium and windows
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
]


@pytest.fixture(scope="module")
def browser() -> Iterator["Browser"]:
    """Debian's Chromium, one per test module."""
    from playwright.sync_api import sync_playwright  # noqa: PLC0415 - only the browser tests need it

    with sync_playwright() as playwright:
        launched = playwright.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
        yield launched
        launched.close()


def _opened(browser: "Browser", **context_options: object) -> Iterator["Page"]:
    context = browser.new_context(**context_options)
    opened = context.new_page()
    opened.set_default_timeout(20_000)
    yield opened
    context.close()


@pytest.fixture
def page(browser: "Browser") -> Iterator["Page"]:
    """A desktop browser window."""
    yield from _opened(browser, viewport={"width": 1360, "height": 900})


@pytest.fixture
def desktop(browser: "Browser") -> Iterator["Page"]:
    """The same desktop window, for tests that name it so beside `phone`."""
    yield from _opened(browser, viewport={"width": 1360, "height": 900})


@pytest.fixture
def phone(browser: "Browser") -> Iterator["Page"]:
    """A phone's browser (touch, 390 x 844)."""
    yield from _opened(browser, viewport={"width": 390, "height": 844}, is_mobile=True, has_touch=True)
