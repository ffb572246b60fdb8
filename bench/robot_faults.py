"""The robot path under faults, judged by the robot's own log: the stand-in robot (bench.logged_standin: the
simulated pusher behind the robot contract, logging every call that moves or holds the arm, its camera opening in
one process at a time) stepped at 5 Hz, two learners (`raq learn`), `raq serve` and an automated person who
presses Ready, through, in turn:

1. SIGSTOP of the learner driving the run for RAQ_STALE_HEARTBEAT_SECONDS + STOP_EXTRA_SECONDS, then SIGCONT
   (the other learner takes the run over meanwhile);
2. SIGKILL of the driving learner, three times, a new learner started after each (as `raq up` restarts one);
3. the database's writes locked for LOCK_SECONDS (another connection holds an exclusive SQLite transaction), the
   arm held meanwhile and resumed by the person after it;
4. the New run form's preview and the Camera panel of a second `raq serve`, while the run acts;
5. Stop robot, then the driving learner SIGSTOPped LEARNER_PAUSE_SECONDS (past the actor's watchdog) and
   SIGCONTed: nothing may move the arm until the person presses Resume, PAUSE_WATCH_SECONDS later;
6. a second `raq robot` for the robot on another host name (it must refuse to start);
7. SIGSTOP of the robot's own process until its row is stale, a new `raq robot` on another host name taking the
   robot over, then SIGCONT: the paused one must let go without touching the arm (with --actor robot).

    python bench/robot_faults.py                  # the robot's own process (`raq robot ENV_ID`) drives every run
    python bench/robot_faults.py --actor remote   # the run has remote_actor and one `raq actor --run ID` drives it

It prints, from the log: the most processes that sent actions within any one control period (one driver: 1), the
shortest interval between two actions, the robot steps lost at the takeovers (the actions the arm took before the
new learner's actor moved it, less the step the run resumed at and the steps lost before: steps no replay got), the
processes of a killed learner still alive STRAY_AFTER_SECONDS later, and the arm
moves made by others: a move by a process that never drove the arm (a server), or an action by a driver after a
later driver's first; the processes other than a driver that opened the robot's camera; the moves after a Stop
nobody resumed (fault 5); and the moves or holds by a process without the hold (the refused robot process of fault
6, the paused one of fault 7 once continued). Writes <out>/figures.json. Every process starts in a process group
of its own, and a SIGSTOPped one is checked to stay stopped for the whole pause (else the bench ends with an error).
"""

import argparse
import contextlib
import json
import os
import re
import signal
import sqlite3
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from app.migrate import upgrade  # noqa: E402
from bench.learn import free_port, wait_for_health  # noqa: E402
from bench.logged_standin import ENV_ID, LOG_VARIABLE, MOVES, calls  # noqa: E402
from bench.processes import on_host, stop_all  # noqa: E402
from bench.robot_standin import add_camera_goal_set, request, resetter  # noqa: E402
from contract.config import TrainConfig  # noqa: E402
from contract.store import RunStatus, Store  # noqa: E402
from robot.drive.process import WAITING_FOR_LEARNER  # noqa: E402

STALE_SECONDS = 10.0
"""RAQ_STALE_HEARTBEAT_SECONDS of the learners: a silent learner's run is taken over after this long."""
STOP_EXTRA_SECONDS = 10.0
"""How long past STALE_SECONDS the driving learner stays stopped."""
KILLS = 3
LOCK_SECONDS = 6.0
STRAY_AFTER_SECONDS = 15.0
"""A killed learner's process still alive this long after the kill is a stray."""
MOVING_SECONDS = 120.0
"""How long the bench waits for the arm to move again after a fault before it says so."""
LEARNER_PAUSE_SECONDS = 8.0
"""How long the driving learner stays SIGSTOPped after a Stop (fault 5)."""
PAUSE_WATCH_SECONDS = 6.0
"""How long after its SIGCONT the bench watches the arm before the person presses Resume."""
ACTORS = ("robot", "remote")
RESUMED = re.compile(r"resumed from checkpoint at step (\d+)")
STARTS_AT = re.compile(r"the actor starts at step (\d+)")


class Bench:
    """The processes and the store of one fault bench."""

    def __init__(self, out: Path, actor: str) -> None:
        self.out = out
        self.log = out / "arm.log"
        data = out / "data"
        data.mkdir(parents=True)
        self.database = data / "raq.sqlite3"
        url = f"sqlite:///{self.database.resolve()}"
        upgrade(url)
        self.store = Store(url)
        config = TrainConfig.cpu_robot(
            env_id=ENV_ID, total_steps=100_000, checkpoint_every=250, eval_every=100_000,
            remote_actor=actor == "remote",
            initial_random_steps=100, query_budget=0,
        )  # fmt: skip
        goal_set_id = add_camera_goal_set(self.store, count=10, image_size=config.image_size)
        self.run_id = self.store.create_run(
            name="faults", env_id=ENV_ID, algorithm=config.algorithm, config=config.to_dict(), seed=0,
            goal_set_id=goal_set_id, total_steps=config.total_steps,
        ).id  # fmt: skip
        self.env = {
            **{key: value for key, value in os.environ.items() if not key.startswith("RAQ_")},
            "RAQ_DATABASE_URL": url, "RAQ_DATA_DIR": str(data), "RAQ_ENV_MODULES": "bench.logged_standin",
            "RAQ_STALE_HEARTBEAT_SECONDS": str(STALE_SECONDS), "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1",
            "OMP_NUM_THREADS": "1", LOG_VARIABLE: str(self.log.resolve()),
        }  # fmt: skip
        self.env.setdefault("MUJOCO_GL", "egl")
        self.processes: list[subprocess.Popen] = []
        self.learners: dict[str, subprocess.Popen] = {}
        self.takeovers: list[dict[str, float | int]] = []
        self.strays: list[int] = []
        self.moves_after_stop = 0
        self.without_hold = 0
        """Moves or holds by a process without the hold."""

    def start(self, name: str, *args: str, host: str | None = None) -> subprocess.Popen:
        log = (self.out / f"{name}.log").open("w")
        command = [sys.executable, "-m", "cli", *args]
        # (a process group of its own: a paused process stays paused whatever its siblings do; in an orphaned group
        # the kernel would SIGCONT every stopped member when one of them exits)
        process = subprocess.Popen(on_host(host, command) if host else command, env=self.env, stdout=log,
                                   stderr=subprocess.STDOUT, cwd=ROOT, process_group=0)  # fmt: skip
        self.processes.append(process)
        return process

    def serve(self, name: str) -> str:
        port = free_port()
        self.start(name, "serve", "--port", str(port))
        url = f"http://127.0.0.1:{port}"
        wait_for_health(url)
        return url

    def wait_for_robot(self) -> None:
        """Until the robot's own process is up and waits for a learner."""
        deadline = time.monotonic() + MOVING_SECONDS
        while (process := self.store.robot_process_of(env_id=ENV_ID)) is None or process.state != WAITING_FOR_LEARNER:
            if time.monotonic() > deadline:
                raise SystemExit("the robot's process did not come up")
            time.sleep(0.2)

    def add_learner(self) -> None:
        name = f"learner-{len(self.learners) + 1}"
        self.learners[name] = self.start(name, "learn", "--name", name)

    def driving(self) -> tuple[str, subprocess.Popen]:
        """The learner that holds the run now."""
        deadline = time.monotonic() + MOVING_SECONDS
        while time.monotonic() < deadline:
            run = self.store.get_run(run_id=self.run_id)
            if run.status == RunStatus.TRAINING and run.worker in self.learners:
                return run.worker, self.learners[run.worker]
            time.sleep(0.5)
        raise SystemExit("no learner trains the run")

    def actions(self, after: float = 0.0) -> list[tuple[float, int]]:
        return [(at, pid) for what, at, pid in calls(self.log) if what == "action" and at > after]

    def wait_for_moves(self, after: float, count: int = 10) -> float:
        """The time of the first action after `after`, once `count` have been sent."""
        deadline = time.monotonic() + MOVING_SECONDS
        while time.monotonic() < deadline:
            moved = self.actions(after)
            if len(moved) >= count:
                return moved[0][0]
            time.sleep(0.5)
        raise SystemExit(f"the arm did not move again within {MOVING_SECONDS:.0f} s")

    def newest_event(self) -> int:
        newest = self.store.events(run_id=self.run_id, limit=1)
        return newest[0].id if newest else 0

    def takeover(self, fault: str, at: float, since_event: int) -> None:
        """After a learner was silenced at `at`: the arm moves again; the step the run resumed at (its events after
        `since_event`) against the actions the arm took before."""
        held = self.wait_for_hold(after=at)
        first = self.wait_for_moves(after=held)
        before = sum(1 for moved, _ in self.actions() if moved < first)
        messages = [event.message for event in self.store.events(run_id=self.run_id, since_id=since_event,
                                                                 limit=100_000)]  # (newest first)  # fmt: skip
        starts = [int(found.group(1)) for message in messages for found in [STARTS_AT.search(message)] if found]
        resumed = [int(found.group(1)) for message in messages for found in [RESUMED.search(message)] if found]
        at_step = starts[0] if starts else resumed[0] if resumed else 0
        lost_so_far = sum(int(takeover["lost"]) for takeover in self.takeovers)
        self.takeovers.append({
            "fault": fault, "actions_before": before, "resumed_at_step": at_step,
            "lost": max(0, before - at_step - lost_so_far), "counted_twice": max(0, at_step + lost_so_far - before),
        })  # fmt: skip
        print(f"{fault}: the arm moved again {first - at:.1f} s later; {before} actions before, the run resumed at "
              f"step {at_step}", flush=True)  # fmt: skip

    def wait_for_hold(self, after: float) -> float:
        """The time the arm was first held after `after` (the silenced learner's actor stopping)."""
        deadline = time.monotonic() + MOVING_SECONDS
        while time.monotonic() < deadline:
            held = [at for what, at, _ in calls(self.log) if what == "hold" and at > after]
            if held:
                return held[0]
            time.sleep(0.2)
        raise SystemExit(f"the arm was not held within {MOVING_SECONDS:.0f} s of the fault")

    def descendants(self, pid: int) -> set[int]:
        found, frontier = set(), {pid}
        while frontier:
            children = set()
            for stat in Path("/proc").glob("[0-9]*/stat"):
                with contextlib.suppress(OSError, ValueError, IndexError):
                    fields = stat.read_text().rpartition(")")[2].split()
                    if int(fields[1]) in frontier and fields[0] != "Z":
                        children.add(int(stat.parent.name))
            frontier = children - found
            found |= children
        return found

    def count_strays(self, pids: set[int]) -> None:
        """The processes of a silenced learner still alive STRAY_AFTER_SECONDS later (a learner that lives on keeps
        its multiprocessing resource tracker, which is no stray)."""
        time.sleep(STRAY_AFTER_SECONDS)
        alive = [pid for pid in pids if _running(pid) and not _tracker_of_a_live_process(pid)]
        self.strays += alive
        if alive:
            print(f"stray processes: {alive}", flush=True)

    def touches(self, pid: int, after: float) -> int:
        """The calls that move or hold the arm made by process `pid` after `after`."""
        return sum(1 for what, at, by in calls(self.log) if what in MOVES and by == pid and at > after)

    def stop_through_a_learner_pause(self, url: str) -> None:
        """Fault 5: Stop, the driving learner paused past the watchdog and continued; Resume only later."""
        self.wait_for_moves(after=time.monotonic(), count=10)
        name, learner = self.driving()
        asked = time.monotonic()
        request(f"{url}/api/runs/{self.run_id}/robot/stop", "POST")
        held = self.wait_for_hold(after=asked)
        learner.send_signal(signal.SIGSTOP)
        stay_paused(learner, LEARNER_PAUSE_SECONDS)
        learner.send_signal(signal.SIGCONT)
        time.sleep(PAUSE_WATCH_SECONDS)
        moved = sum(1 for what, at, _ in calls(self.log) if what in ("action", "reset") and at > held)
        self.moves_after_stop += moved
        print(f"Stop, then SIGSTOP {name} {LEARNER_PAUSE_SECONDS:g} s and SIGCONT: {moved} moves before Resume",
              flush=True)  # fmt: skip
        request(f"{url}/api/runs/{self.run_id}/robot/resume", "POST")
        self.wait_for_moves(after=time.monotonic(), count=10)

    def second_robot_process(self) -> None:
        """Fault 6: `raq robot` for the same robot on another host name; it must refuse, touching nothing."""
        started = time.monotonic()
        second = self.start("robot-refused", "robot", ENV_ID, host="robotpc2")
        code = second.wait(timeout=MOVING_SECONDS)
        touched = self.touches(second.pid, started)
        self.without_hold += touched
        print(f"a second robot process on another host: exit code {code}, {touched} moves or holds", flush=True)

    def robot_process_paused(self, robot: subprocess.Popen, url: str) -> subprocess.Popen:
        """Fault 7: the robot's process SIGSTOPped until its row is stale, a new one takes the robot's row (its
        camera waits: the paused one still has it open), then SIGCONT: the paused one must let go and end. A person
        resumes the arm if the store's silence left it stopped."""
        self.wait_for_moves(after=time.monotonic(), count=10)
        robot.send_signal(signal.SIGSTOP)
        while self.store.robot_process_of(env_id=ENV_ID) is not None:
            time.sleep(0.2)
        successor = self.start("robot-2", "robot", ENV_ID, host="robotpc3")
        while (serving := self.store.robot_process_of(env_id=ENV_ID)) is None or serving.holder.endswith("@robotpc"):
            time.sleep(0.2)
        robot.send_signal(signal.SIGCONT)
        continued = time.monotonic()
        code = robot.wait(timeout=MOVING_SECONDS)
        time.sleep(2.0)
        touched = self.touches(robot.pid, continued)
        self.without_hold += touched
        print(f"the robot's process paused and taken over: it exited {code}, {touched} moves or holds after SIGCONT",
              flush=True)  # fmt: skip
        request(f"{url}/api/runs/{self.run_id}/robot/resume", "POST")
        self.wait_for_moves(after=continued, count=10)
        return successor

    def lock_database(self, seconds: float) -> None:
        connection = sqlite3.connect(self.database, timeout=30)
        try:
            connection.execute("BEGIN EXCLUSIVE")
            time.sleep(seconds)
        finally:
            connection.rollback()
            connection.close()


def stay_paused(process: subprocess.Popen, seconds: float) -> None:
    """Wait `seconds` while the SIGSTOPped `process` stays stopped; a process continued meanwhile by anybody else
    would make the fault another one, so the bench says so and ends."""
    started = time.monotonic()
    while time.monotonic() < started + seconds:
        with contextlib.suppress(OSError):
            state = Path(f"/proc/{process.pid}/stat").read_text().rpartition(")")[2].split()[0]
            if state not in ("T", "t") and time.monotonic() > started + 0.5:  # (the stop itself takes a moment)
                raise SystemExit(f"process {process.pid} was continued by another signal after its SIGSTOP")
        time.sleep(0.1)


def _tracker_of_a_live_process(pid: int) -> bool:
    try:
        command = Path(f"/proc/{pid}/cmdline").read_bytes()
        parent = int(Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[1])
    except (OSError, ValueError, IndexError):
        return False
    return b"resource_tracker" in command and parent != 1 and _running(parent)


def _running(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0] != "Z"
    except OSError:
        return False


def figures(log: Path, period: float, bench: Bench) -> dict:
    """The figures from the arm's log (see the module's docstring)."""
    entries = calls(log)
    actions = [(at, pid) for what, at, pid in entries if what == "action"]
    most = max((len({pid for other, pid in actions if at <= other < at + period}) for at, _ in actions), default=0)
    gaps = [later - earlier for (earlier, _), (later, _) in zip(actions, actions[1:], strict=False)]
    drivers = {pid for _, pid in actions}
    first_action = {pid: min(at for at, other in actions if other == pid) for pid in drivers}
    by_others = sum(1 for what, _, pid in entries if what in MOVES and pid not in drivers)
    camera_by_others = sum(1 for what, _, pid in entries if what == "open" and pid not in drivers)
    displaced = sum(
        1 for at, pid in actions if any(start > first_action[pid] and start < at for start in first_action.values())
    )
    return {
        "most_drivers_at_once": most,
        "shortest_interval_ms": round(min(gaps) * 1000, 1) if gaps else None,
        "steps_lost": sum(int(t["lost"]) for t in bench.takeovers),
        "steps_counted_twice": sum(int(t["counted_twice"]) for t in bench.takeovers),
        "stray_processes": len(bench.strays),
        "arm_moves_by_others": by_others + displaced,
        "camera_opened_by_others": camera_by_others,
        "moves_after_stop": bench.moves_after_stop,
        "moves_or_holds_without_hold": bench.without_hold,
        "actions": len(actions),
        "drivers": len(drivers),
        "takeovers": bench.takeovers,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--actor", choices=ACTORS, default="robot",
        help="who drives the arm: the robot's own process (default), or one `raq actor --run ID` for a remote_actor "
        "run",
    )  # fmt: skip
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "out" / "robot-faults")
    args = parser.parse_args()
    out = args.out / args.actor
    if out.exists():
        raise SystemExit(f"{out} exists: remove it or choose another --out")
    bench = Bench(out, args.actor)
    done, presses = threading.Event(), []
    period = 0.2
    try:
        url = bench.serve("serve")
        threading.Thread(target=resetter, args=(url, done, presses), daemon=True).start()
        robot = None
        if args.actor == "remote":
            bench.start("actor", "actor", "--run", str(bench.run_id))
        else:
            robot = bench.start("robot", "robot", ENV_ID, host="robotpc")
            bench.wait_for_robot()
        bench.add_learner()
        bench.add_learner()
        bench.wait_for_moves(after=0.0, count=30)
        print("the arm moves: faults begin", flush=True)

        name, learner = bench.driving()
        since = bench.newest_event()
        learner.send_signal(signal.SIGSTOP)
        stopped = time.monotonic()
        children = bench.descendants(learner.pid)
        print(f"SIGSTOP {name}", flush=True)
        stay_paused(learner, STALE_SECONDS + STOP_EXTRA_SECONDS)
        learner.send_signal(signal.SIGCONT)
        bench.takeover("SIGSTOP past the stale time", stopped, since)
        bench.count_strays(children)

        for kill in range(KILLS):
            bench.wait_for_moves(after=time.monotonic(), count=10)
            name, learner = bench.driving()
            children, since = bench.descendants(learner.pid), bench.newest_event()
            learner.send_signal(signal.SIGKILL)
            killed = time.monotonic()
            print(f"SIGKILL {name} ({kill + 1} of {KILLS})", flush=True)
            bench.add_learner()
            bench.takeover(f"SIGKILL {kill + 1}", killed, since)
            bench.count_strays(children)

        bench.wait_for_moves(after=time.monotonic(), count=10)
        print(f"the database's writes locked for {LOCK_SECONDS:g} s", flush=True)
        bench.lock_database(LOCK_SECONDS)
        time.sleep(2.0)  # the actor held the arm when the database went silent; a person resumes it
        request(f"{url}/api/runs/{bench.run_id}/robot/resume", "POST")
        bench.wait_for_moves(after=time.monotonic(), count=10)

        second = bench.serve("serve-2")
        answers = []
        for _ in range(10):
            for path in (f"/api/envs/preview?env_id={ENV_ID}&size=48", f"/api/cameras/frame?env_id={ENV_ID}"):
                try:
                    with urllib.request.urlopen(second + path, timeout=30) as response:
                        answers.append(response.status)
                except urllib.error.HTTPError as error:
                    answers.append(error.code)
            time.sleep(0.5)
        print(f"a second server's previews and Camera panel: answers {sorted(set(answers))}", flush=True)
        bench.wait_for_moves(after=time.monotonic(), count=10)

        bench.stop_through_a_learner_pause(url)
        if robot is not None:
            bench.second_robot_process()
            bench.robot_process_paused(robot, url)
    finally:
        done.set()
        with contextlib.suppress(Exception):
            request(f"{url}/api/runs/{bench.run_id}/stop", "POST")
        for process in bench.processes:
            with contextlib.suppress(OSError):
                process.send_signal(signal.SIGCONT)
        stop_all(bench.processes, signal.SIGINT, timeout=60)
    result = figures(bench.log, period, bench) | {"actor": args.actor, "resets_pressed": len(presses)}
    (out / "figures.json").write_text(json.dumps(result, indent=2) + "\n")
    print(
        f"most drivers at once: {result['most_drivers_at_once']}, steps lost: {result['steps_lost']}, "
        f"stray processes: {result['stray_processes']}, arm moves by others: {result['arm_moves_by_others']}"
    )
    print(f"moves after a Stop: {result['moves_after_stop']}, moves or holds by a process without the hold: "
          f"{result['moves_or_holds_without_hold']}")  # fmt: skip
    print(f"shortest interval between two actions: {result['shortest_interval_ms']} ms; "
          f"steps counted twice: {result['steps_counted_twice']}; "
          f"camera opened by others: {result['camera_opened_by_others']}")  # fmt: skip
    bench.store.dispose()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
