"""`raq up` starts the web server and a learner on one SQLite file, answers /health, and stops on Ctrl-C."""

import json
import os
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import IO

from conftest import ROOT, create_run, free_port
from sqlalchemy import func, select

from contract.store import LoginFailure, Store


def wait_for_health(port: int, process: subprocess.Popen, timeout: float = 90) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert process.poll() is None, f"raq exited early with {process.returncode}"
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=2) as response:
                return json.loads(response.read())
        except OSError:
            time.sleep(0.5)
    raise AssertionError("no answer on /health")


def start_raq_up(
    tmp_path: Path, *arguments: str, settings: dict[str, str] | None = None
) -> tuple[subprocess.Popen, int, IO[str]]:
    """`raq up` on a SQLite file in tmp_path, in a session of its own (as a terminal runs it); and its port and log."""
    port = free_port()
    env = {**os.environ, "RAQ_DATA_DIR": str(tmp_path), "RAQ_PORT": str(port), "PYTHONUNBUFFERED": "1"}
    env.update(settings or {})
    env.pop("RAQ_DATABASE_URL", None)
    env.pop("DATABASE_URL", None)
    log = (tmp_path / "up.log").open("w")
    process = subprocess.Popen(
        [sys.executable, "-m", "cli", "up", *arguments], env=env, stdout=log, stderr=subprocess.STDOUT,
        start_new_session=True,
    )  # fmt: skip
    return process, port, log


def test_raq_up_serves_health_runs_a_learner_and_stops_cleanly(tmp_path: Path) -> None:
    process, port, log = start_raq_up(tmp_path)
    try:
        assert wait_for_health(port, process) == {"status": "ok", "database": "ok"}
        # The learner shares the same SQLite file: a run queued there is claimed by it.
        store = Store(f"sqlite:///{tmp_path / 'raq.sqlite3'}")
        run = store.create_run(env_id="no-such-env-v0", algorithm="sparse", config={"env_id": "no-such-env-v0"})
        deadline = time.monotonic() + 60
        while store.get_run(run_id=run.id).status in ("queued", "starting", "training"):
            assert time.monotonic() < deadline, "the learner never took the run"
            time.sleep(0.5)
        failed = store.get_run(run_id=run.id)
        assert failed.status == "failed" and "no-such-env" in failed.status_reason  # the reason is kept
        store.dispose()
    finally:
        os.killpg(process.pid, signal.SIGINT)  # what Ctrl-C in a terminal sends
        code = process.wait(timeout=60)
        log.close()
    output = (tmp_path / "up.log").read_text()
    assert code == 0, output
    assert "web" in output and "learner" in output and "raq up: stopped" in output


def test_raq_up_starts_the_robots_it_is_told_of_and_starts_one_again_after_a_crash(tmp_path: Path) -> None:
    standin = "robot.standin:PusherStandIn-v0"
    process, port, log = start_raq_up(tmp_path, settings={"RAQ_ROBOTS": standin, "MUJOCO_GL": "egl"})
    store = Store(f"sqlite:///{tmp_path / 'raq.sqlite3'}")

    def robot_up(other_than: str | None = None) -> str:
        deadline = time.monotonic() + 90
        while (row := store.robot_process_of(env_id=standin)) is None or row.holder == other_than:
            assert time.monotonic() < deadline and process.poll() is None, (tmp_path / "up.log").read_text()
            time.sleep(0.5)
        return row.holder

    try:
        wait_for_health(port, process)
        first = robot_up()
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/cameras/frame?env_id={standin}", timeout=30) as got:
            assert got.status == 200 and got.headers["X-Camera-Source"].startswith("robot ")  # from its process
        os.kill(int(first.split("@")[0]), signal.SIGKILL)
        assert robot_up(other_than=first) != first  # started again
    finally:
        os.killpg(process.pid, signal.SIGINT)
        code = process.wait(timeout=60)
        log.close()
    output = (tmp_path / "up.log").read_text()
    assert code == 0, output
    assert "robot-1 | robot robot.standin:PusherStandIn-v0: interrupted: the arm is held safe" in output
    assert store.robot_process_of(env_id=standin) is None  # its row went with it
    store.dispose()


def test_raq_up_starts_the_process_of_a_robot_whose_run_waits_for_it(tmp_path: Path) -> None:
    """No RAQ_ROBOTS: a run of a robot env is created, raq up's learner claims it and waits (it never drives a robot
    itself), and raq up starts the robot's own process on its host, which drives the run."""
    from recording_arm import ENV_ID, LOG_VARIABLE, recorded_by  # noqa: PLC0415
    from test_actor import real_time_config  # noqa: PLC0415

    from learner.testing_envs import add_dot_goals  # noqa: PLC0415

    arm_log = tmp_path / "arm.log"
    settings = {
        "RAQ_ENV_MODULES": "learner.testing_envs,recording_arm", "PYTHONPATH": str(ROOT / "tests"),
        LOG_VARIABLE: str(arm_log), "OMP_NUM_THREADS": "1",
    }  # fmt: skip
    process, port, log = start_raq_up(tmp_path, "--learners", "1", settings=settings)
    store = Store(f"sqlite:///{tmp_path / 'raq.sqlite3'}")
    try:
        wait_for_health(port, process)
        config = real_time_config(env_id=ENV_ID, total_steps=100_000, reset_every_episode=False, episode_steps=30)
        run_id = create_run(store, add_dot_goals(store), config)
        deadline = time.monotonic() + 120
        while store.get_run(run_id=run_id).step < 20:
            assert time.monotonic() < deadline and process.poll() is None, (tmp_path / "up.log").read_text()
            time.sleep(0.5)
        robot = store.robot_process_of(env_id=ENV_ID)
        assert robot is not None and robot.state == f"driving run {run_id}"
        assert {pid for what, _, pid in recorded_by(arm_log) if what == "action"} == {int(robot.holder.split("@")[0])}
    finally:
        os.killpg(process.pid, signal.SIGINT)
        process.wait(timeout=60)
        log.close()
        store.dispose()
    output = (tmp_path / "up.log").read_text()
    assert f"a run waits for robot {ENV_ID}; starting its process here" in output, output


def server_workers(supervisor: int) -> list[int]:
    """The worker processes uvicorn's supervisor spawned (not multiprocessing's resource tracker)."""
    children = subprocess.run(["pgrep", "-P", str(supervisor)], capture_output=True, text=True).stdout.split()
    return [int(pid) for pid in children if "spawn_main" in Path(f"/proc/{pid}/cmdline").read_text(errors="replace")]


def test_raq_serve_with_two_workers_shares_the_login_limit_between_its_processes(tmp_path: Path) -> None:
    """`raq serve --workers 2`: two server processes on one SQLite file; wrong tokens sent on fresh connections
    (which either process may take) count against one limit: every try after the third is refused, whichever
    process takes it."""
    port = free_port()
    env = {
        **os.environ, "RAQ_DATA_DIR": str(tmp_path), "RAQ_PORT": str(port), "RAQ_API_TOKEN": "the-token",
        "RAQ_LOGIN_ATTEMPTS_PER_MINUTE": "3", "PYTHONUNBUFFERED": "1",
    }  # fmt: skip
    env.pop("RAQ_DATABASE_URL", None)
    env.pop("DATABASE_URL", None)
    log = (tmp_path / "serve.log").open("w")
    process = subprocess.Popen(
        [sys.executable, "-m", "cli", "serve", "--workers", "2"], env=env, stdout=log, stderr=subprocess.STDOUT,
        start_new_session=True,
    )  # fmt: skip
    try:
        wait_for_health(port, process)
        deadline = time.monotonic() + 60  # uvicorn's supervisor spawns its worker processes
        while len(server_workers(process.pid)) < 2:
            assert time.monotonic() < deadline, "two worker processes never ran"
            time.sleep(0.5)
        statuses = []
        for _ in range(13):
            request = urllib.request.Request(
                f"http://127.0.0.1:{port}/login", data=b"token=guess", method="POST",
                headers={"Content-Type": "application/x-www-form-urlencoded", "Connection": "close"},
            )  # fmt: skip
            try:
                urllib.request.urlopen(request, timeout=10)
            except urllib.error.HTTPError as error:
                statuses.append(error.code)
        assert statuses == [401] * 3 + [429] * 10
        store = Store(f"sqlite:///{tmp_path / 'raq.sqlite3'}")
        with store.reading() as session:  # the three wrong tokens, counted once each, the refused tries not
            assert session.scalar(select(func.count()).select_from(LoginFailure)) == 3
        store.dispose()
    finally:
        os.killpg(process.pid, signal.SIGINT)
        process.wait(timeout=60)
        log.close()


def learner_processes(supervisor: int) -> list[int]:
    """`raq learn` children of `raq up`."""
    children = subprocess.run(["pgrep", "-P", str(supervisor)], capture_output=True, text=True).stdout.split()
    return [int(pid) for pid in children if b"learn" in Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")]


def test_raq_up_starts_a_learner_that_exits_again_and_keeps_the_server(tmp_path: Path) -> None:
    process, port, log = start_raq_up(tmp_path, "--learners", "1")
    try:
        wait_for_health(port, process)
        deadline = time.monotonic() + 30
        while not learner_processes(process.pid):
            assert time.monotonic() < deadline, "no learner started"
            time.sleep(0.2)
        (first,) = learner_processes(process.pid)
        os.kill(first, signal.SIGKILL)
        deadline = time.monotonic() + 30
        while not [pid for pid in learner_processes(process.pid) if pid != first]:
            assert process.poll() is None, (tmp_path / "up.log").read_text()
            assert time.monotonic() < deadline, "the learner was not started again"
            time.sleep(0.2)
        assert wait_for_health(port, process) == {"status": "ok", "database": "ok"}  # the server stayed up
    finally:
        os.killpg(process.pid, signal.SIGINT)
        code = process.wait(timeout=60)
        log.close()
    output = (tmp_path / "up.log").read_text()
    assert "learner exited with code -9; starting it again" in output, output
    assert code == 0 and "raq up: stopped" in output
