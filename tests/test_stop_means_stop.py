"""Stop means stop: an arm moves only when its own process has armed it, holds it, and no Stop is pending.

Each test runs real processes (`raq robot`, a learner) on the recording arm, whose log names the process of every
call that moves or holds it, and sends them real signals:
- a Stop, then the learner paused 8 s (SIGSTOP) and continued: no move until a person presses Resume;
- a learner that starts before any robot process, on another host name than the robot's: it never drives the arm,
  its run says how to start the robot's process; a second robot process for the robot, on a third host name,
  refuses to start and names the first;
- a robot registered through a factory function: the server's preview and the learner never move it;
- the robot process's link to the store goes silent (a TCP proxy that stops forwarding): the arm is held within
  the watchdog time, and nothing moves until the link is back and a person presses Resume;
- a robot process paused while another takes the robot over: continued, it lets go, touching nothing.
"""

import os
import selectors
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from conftest import ROOT, create_run, learn_once_beside, robot_subprocess
from recording_arm import ENV_ID, FACTORY_ENV_ID, LOG_VARIABLE, recorded_by
from test_actor import arm_env, real_time_config

from bench.processes import on_host
from contract.settings import Settings, get_settings
from contract.store import RunStatus, Store
from learner.testing_envs import add_dot_goals

MOVES = ("action", "reset")
"""The arm log's words for a call that moves the arm ("hold" holds it)."""


@contextmanager
def learner_process(env: dict[str, str], log: Path, host: str | None = None) -> Iterator[subprocess.Popen]:
    """A learner worker (`--once`) in a process of its own, its output in `log`; killed at the end."""
    command = [sys.executable, "-m", "learner.worker", "--once", "--name", "learner"]
    with log.open("wb") as output:
        process = subprocess.Popen(
            on_host(host, command) if host else command,
            cwd=ROOT,
            env=env,
            stdout=output,
            stderr=subprocess.STDOUT,
            process_group=0,  # (paused by a test, it stays paused whatever the processes beside it do)
        )
        try:
            yield process
        finally:
            if process.poll() is None:
                os.kill(process.pid, signal.SIGCONT)
                process.kill()
            process.wait(timeout=30)


def wait_until(condition: Callable[[], object], seconds: float, what: str) -> None:
    deadline = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < deadline, f"not within {seconds:g} s: {what}"
        time.sleep(0.05)


def calls_after(log: Path, moment: float, kinds: tuple[str, ...] = MOVES, pid: int | None = None) -> list[float]:
    return [at for what, at, by in recorded_by(log) if what in kinds and at > moment and pid in (None, by)]


def a_run(store: Store, env_id: str = ENV_ID, **overrides: object) -> int:
    """A long run of the recording arm (no person's reset), its goals DotReach's (added once a store)."""
    values: dict[str, object] = {"total_steps": 100_000, "reset_every_episode": False, "episode_steps": 30}
    config = real_time_config(env_id=env_id, **{**values, **overrides})
    goal_set = next((found.id for found, _ in store.list_goal_sets() if found.name == "dot"), None)
    return create_run(store, goal_set or add_dot_goals(store), config)


@pytest.fixture
def arm(dot_reach: tuple[Settings, Store, int], tmp_path: Path, monkeypatch: pytest.MonkeyPatch):  # type: ignore[no-untyped-def]
    """(settings, store, the arm's log) with the recording arm's module allowed here too."""
    settings, store, _ = dot_reach
    log = tmp_path / "arm.log"
    monkeypatch.setenv("RAQ_ENV_MODULES", "learner.testing_envs,recording_arm")
    monkeypatch.setenv(LOG_VARIABLE, str(log))
    get_settings.cache_clear()
    yield settings, store, log
    get_settings.cache_clear()


def test_a_stop_holds_through_a_learner_that_goes_quiet_for_8_s_until_a_person_presses_resume(
    arm: tuple[Settings, Store, Path], tmp_path: Path
) -> None:
    """Stop robot, then the learner SIGSTOPped 8 s (past the actor's watchdog: the actor exits on "learner gone")
    and SIGCONTed: the robot's process drives the run again, and neither it nor anybody moves the arm (no reset, no
    action) until Resume; then the run goes on from the step it had reached."""
    settings, store, log = arm
    run_id = a_run(store)
    env = arm_env(settings, log)
    with (
        robot_subprocess(env, ENV_ID, store, tmp_path / "robot.log") as robot,
        learner_process(env, tmp_path / "learner.log") as learner,
    ):
        wait_until(lambda: len(calls_after(log, 0.0, ("action",))) >= 20, 120, "the robot driven")
        store.request_robot_stop(run_id=run_id)
        # (held, or let go where the store was too slow to confirm the hold lately: either way, no move from here)
        wait_until(lambda: store.robot_status(run_id=run_id).actor_state == "stopped", 10, "the Stop honoured")
        held = time.monotonic()
        step_at_stop = store.get_run(run_id=run_id).step
        learner.send_signal(signal.SIGSTOP)
        time.sleep(8.0)
        learner.send_signal(signal.SIGCONT)
        continued = time.monotonic()
        wait_until(
            lambda: (process := store.robot_process_of(env_id=ENV_ID)) is not None
            and process.state == f"driving run {run_id}" and store.robot_status(run_id=run_id).actor_state == "stopped"
            and (store.actor_link(run_id=run_id).actor_age_seconds or 99) < 1.0,
            20, "the run driven again, stopped",
        )  # fmt: skip
        time.sleep(3.0)
        assert calls_after(log, held) == [], "the arm moved after a Stop nobody resumed"
        assert {pid for _, _, pid in recorded_by(log)} == {robot.pid}
        assert "driving run" in (tmp_path / "robot.log").read_text()
        store.resume_robot(run_id=run_id)
        resumed = time.monotonic()
        wait_until(lambda: len(calls_after(log, resumed, ("action",))) >= 5, 20, "the arm moving after Resume")
        assert continued < resumed
        assert store.get_run(run_id=run_id).step >= step_at_stop
    output = (tmp_path / "robot.log").read_text()
    assert output.count(f"driving run {run_id}") >= 2, output  # (driven again after the learner's silence)


def test_a_learner_on_another_host_never_drives_and_a_second_robot_process_refuses(
    arm: tuple[Settings, Store, Path], tmp_path: Path
) -> None:
    """The learner starts on "gpubox" while no robot process is up: it moves nothing and its run says how to start
    one. `raq robot` on "robotpc" drives the run alone; a second `raq robot` for the same robot on "robotpc2" exits
    1 naming the first, having touched nothing."""
    settings, store, log = arm
    run_id = a_run(store)
    env = arm_env(settings, log)
    with learner_process(env, tmp_path / "learner.log", host="gpubox") as learner:
        wait_until(lambda: store.get_run(run_id=run_id).status != RunStatus.QUEUED, 60, "the run claimed")
        wait_until(
            lambda: any("raq robot" in event.message for event in store.events(run_id=run_id)), 30,
            "the run to say how to start the robot's process",
        )  # fmt: skip
        time.sleep(2.0)
        assert recorded_by(log) == [] and learner.poll() is None
        command = on_host("robotpc", [sys.executable, "-m", "cli", "robot", ENV_ID])
        with (tmp_path / "robot.log").open("wb") as output:
            robot = subprocess.Popen(command, cwd=ROOT, env=env, stdout=output, stderr=subprocess.STDOUT)
        try:
            wait_until(lambda: len(calls_after(log, 0.0, ("action",))) >= 20, 120, "the robot driven")
            second = subprocess.run(
                on_host("robotpc2", [sys.executable, "-m", "cli", "robot", ENV_ID]), cwd=ROOT, env=env,
                capture_output=True, text=True, timeout=120,
            )  # fmt: skip
            assert second.returncode == 1, second.stdout + second.stderr
            holder = store.robot_process_of(env_id=ENV_ID).holder
            assert holder.endswith("@robotpc") and f"served by process {holder}" in second.stderr
            time.sleep(1.0)
            assert {pid for _, _, pid in recorded_by(log)} == {robot.pid}
        finally:
            robot.send_signal(signal.SIGINT)
            robot.wait(timeout=30)


def test_a_robot_registered_by_a_factory_function_is_never_moved_by_the_server_or_the_learner(
    arm: tuple[Settings, Store, Path],
    make_client,
    tmp_path: Path,  # type: ignore[no-untyped-def]
) -> None:
    """Its registration cannot say it is a robot. The New run form's preview answers with the robot's (grey) frame,
    the server's process touching nothing; a run of it created through the API trains through the robot's own
    process, and only that process moves the arm."""
    settings, store, log = arm
    client = make_client(env_modules=("learner.testing_envs", "recording_arm"))
    for _ in range(2):  # (made once to find out, then answered as a robot)
        preview = client.get("/api/envs/preview", params={"env_id": FACTORY_ENV_ID, "size": 16})
        assert preview.status_code == 200, preview.text
        assert "robot" in preview.json()["description"], preview.json()
    assert [what for what, _, _ in recorded_by(log)] == []
    with robot_subprocess(arm_env(settings, log), FACTORY_ENV_ID, store, tmp_path / "robot.log") as robot:
        run_id = a_run(store, env_id=FACTORY_ENV_ID, total_steps=60)
        assert learn_once_beside(settings, lambda done: done.wait()) == 0
        assert store.get_run(run_id=run_id).status == RunStatus.FINISHED
        movers = {pid for what, _, pid in recorded_by(log) if what in (*MOVES, "hold")}
        assert movers == {robot.pid}


# ---------------------------------------------------------------- a store link that goes silent
class SilentProxy:
    """A TCP proxy on 127.0.0.1 to `port` that forwards until `silence()`: then it reads and sends nothing (the
    connections stay open, as behind a pulled cable) until `heal()`."""

    def __init__(self, port: int) -> None:
        self.target = port
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.forwarding = threading.Event()
        self.forwarding.set()
        self.closed = False
        threading.Thread(target=self._accept, daemon=True).start()

    def silence(self) -> None:
        self.forwarding.clear()

    def heal(self) -> None:
        self.forwarding.set()

    def close(self) -> None:
        self.closed = True
        self.forwarding.set()
        self.listener.close()

    def _accept(self) -> None:
        while not self.closed:
            try:
                client, _ = self.listener.accept()
            except OSError:
                return
            server = socket.create_connection(("127.0.0.1", self.target))
            threading.Thread(target=self._pump, args=(client, server), daemon=True).start()

    def _pump(self, client: socket.socket, server: socket.socket) -> None:
        selector = selectors.DefaultSelector()
        selector.register(client, selectors.EVENT_READ, server)
        selector.register(server, selectors.EVENT_READ, client)
        try:
            while not self.closed:
                self.forwarding.wait()
                for key, _ in selector.select(timeout=0.05):
                    if not self.forwarding.is_set():
                        break
                    data = key.fileobj.recv(65536)  # type: ignore[union-attr]
                    if not data:
                        return
                    key.data.sendall(data)
        except OSError:
            return
        finally:
            client.close()
            server.close()


def test_a_silent_store_link_ends_with_the_arm_held_within_the_watchdog_time(
    fresh_postgres: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The robot's process reaches PostgreSQL through a proxy that stops forwarding mid-run (the learner reaches it
    directly): the arm is held within the watchdog time and moves no more; once the link is back it stays held
    until a person presses Resume."""
    log = tmp_path / "arm.log"
    monkeypatch.setenv("RAQ_ENV_MODULES", "learner.testing_envs,recording_arm")
    get_settings.cache_clear()
    settings = Settings(_env_file=None, data_dir=tmp_path / "data", database_url=fresh_postgres)  # type: ignore[call-arg]
    store = Store(fresh_postgres)
    run_id = a_run(store)
    watchdog = real_time_config().watchdog_seconds
    host, port = fresh_postgres.split("@", 1)[1].split("/", 1)[0].split(":")
    proxy = SilentProxy(int(port))
    proxied = fresh_postgres.replace(f"{host}:{port}", f"127.0.0.1:{proxy.port}")
    try:
        with (
            robot_subprocess(arm_env(settings, log, proxied), ENV_ID, store, tmp_path / "robot.log"),
            learner_process(arm_env(settings, log), tmp_path / "learner.log"),
        ):
            wait_until(lambda: len(calls_after(log, 0.0, ("action",))) >= 20, 120, "the robot driven")
            proxy.silence()
            silent = time.monotonic()
            wait_until(lambda: calls_after(log, silent, ("hold",)), watchdog + 1.0, "the arm held")
            held = calls_after(log, silent, ("hold",))[0]
            assert held - silent <= watchdog + 0.5, held - silent
            assert [at for at in calls_after(log, silent) if at > silent + 0.6] == []
            time.sleep(2.0)
            proxy.heal()
            healed = time.monotonic()
            wait_until(lambda: store.robot_status(run_id=run_id).stop_requested, 20, "the run marked stopped")
            time.sleep(2.0)
            assert calls_after(log, held) == [], "the arm moved before anybody pressed Resume"
            store.resume_robot(run_id=run_id)
            wait_until(lambda: calls_after(log, healed, ("action",)), 30, "the arm moving after Resume")
    finally:
        proxy.close()
        store.dispose()
        get_settings.cache_clear()


def test_a_robot_process_paused_while_another_takes_the_robot_over_lets_go_when_continued(
    arm: tuple[Settings, Store, Path], tmp_path: Path
) -> None:
    """The robot's process is SIGSTOPped mid-run; once its row is stale a new `raq robot` takes the robot over and
    drives the run. The first, SIGCONTed, neither holds nor moves the arm: it lets go and ends."""
    settings, store, log = arm
    a_run(store)
    env = arm_env(settings, log)
    with (
        robot_subprocess(env, ENV_ID, store, tmp_path / "first.log") as first,
        learner_process(env, tmp_path / "learner.log"),
    ):
        wait_until(lambda: len(calls_after(log, 0.0, ("action",))) >= 20, 120, "the robot driven")
        first.send_signal(signal.SIGSTOP)
        paused = time.monotonic()
        wait_until(lambda: store.robot_process_of(env_id=ENV_ID) is None, 15, "the paused process's row stale")
        command = on_host("robotpc2", [sys.executable, "-m", "cli", "robot", ENV_ID])
        with (tmp_path / "second.log").open("wb") as output:
            second = subprocess.Popen(command, cwd=ROOT, env=env, stdout=output, stderr=subprocess.STDOUT)
        try:
            wait_until(lambda: len(calls_after(log, paused, ("action",), second.pid)) >= 10, 60, "the robot taken over")
            first.send_signal(signal.SIGCONT)
            continued = time.monotonic()
            first.wait(timeout=30)
            time.sleep(1.0)
            assert calls_after(log, continued, (*MOVES, "hold"), first.pid) == []
            assert calls_after(log, continued, ("action",), second.pid)
        finally:
            second.send_signal(signal.SIGINT)
            second.wait(timeout=30)
    assert first.returncode == 1 and "displaced" in (tmp_path / "first.log").read_text()
