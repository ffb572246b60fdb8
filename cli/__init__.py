"""The `raq` command: serve, learn, robot, actor, up, oracle, goals, migrate, sessions, config."""

import argparse
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence

from contract.settings import Settings, get_settings

LOOPBACK_HOSTS = {"127.0.0.1", "localhost", "::1"}


def _migrate(settings: Settings) -> None:
    from app.migrate import upgrade

    upgrade(settings.resolved_database_url)


def cmd_migrate(args: argparse.Namespace) -> int:
    settings = get_settings()
    _migrate(settings)
    print(f"database at head: {settings.resolved_database_url}", flush=True)
    return 0


def cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    settings = get_settings()
    host = args.host or settings.host
    port = args.port or settings.port
    if host not in LOOPBACK_HOSTS and not settings.api_token:
        print(
            f"refusing to bind {host}: without RAQ_API_TOKEN the server binds 127.0.0.1 only "
            "(set RAQ_API_TOKEN to serve other hosts)",
            file=sys.stderr,
        )
        return 2
    if not 1 <= args.workers <= 64:
        print("raq serve: --workers must be 1 to 64", file=sys.stderr)
        return 2
    _migrate(settings)
    # Several processes share nothing but the database (the login rate limit and sessions live there too).
    # X-Forwarded-For is read by the app itself, only from RAQ_TRUSTED_PROXIES (uvicorn's own trusts loopback).
    uvicorn.run(
        "app.main:create_app", factory=True, host=host, port=port, log_level=args.log_level, workers=args.workers,
        proxy_headers=False,
    )  # fmt: skip
    return 0


def cmd_learn(args: argparse.Namespace) -> int:
    settings = get_settings()
    _migrate(settings)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    from learner.worker import work

    print(f"learner: taking queued runs from {settings.resolved_database_url}", flush=True)

    return work(settings, worker_name=args.name, once=args.once)


def _serve_robot(env_id: str | None, run_id: int | None) -> int:
    """The robot's own process (robot/drive/process.py) until Ctrl-C, SIGTERM, or the one run it serves ends, its
    actors acting with the learner's SAC policy."""
    settings = get_settings()
    from contract.store import Store
    from learner.acting import SAC_ACTING
    from robot.drive.process import serve_robot

    def _interrupt(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, _interrupt)
    store = Store(settings.resolved_database_url)
    if run_id is not None:
        env_id = store.get_run(run_id=run_id).env_id
    assert env_id is not None
    what = f"robot {env_id}" + (f" (run {run_id} only)" if run_id is not None else "")
    print(f"{what}: serving its camera and driving its runs through {settings.resolved_database_url}", flush=True)
    from contract.store.robot_processes import RobotServed

    try:
        ended = serve_robot(
            store, env_id=env_id, checkpoint_base=settings.resolved_checkpoint_url, acting=SAC_ACTING, only_run=run_id
        )
    except KeyboardInterrupt:
        ended = "interrupted: the arm is held safe"
    except RobotServed as error:  # (nothing was opened, nothing moved)
        print(f"raq robot: {error}", file=sys.stderr, flush=True)
        return 1
    print(f"{what}: {ended}", flush=True)
    return 1 if ended.startswith("displaced") else 0


def cmd_robot(args: argparse.Namespace) -> int:
    """Own a robot on this host: its camera for the pages, its arm for whichever run's learner links to it."""
    from contract.envs import env_id_problem

    problem = env_id_problem(args.env_id, allowed_modules=get_settings().env_modules)
    if problem is not None:
        print(f"raq robot: {problem}", file=sys.stderr)
        return 2
    return _serve_robot(args.env_id, None)


def cmd_actor(args: argparse.Namespace) -> int:
    """Drive one run's robot from this host for its learner elsewhere, linked by the database and checkpoint store."""
    return _serve_robot(None, args.run)


def cmd_config(_args: argparse.Namespace) -> int:
    """Every field of a run's configuration by part, with its default, as markdown (docs/configuration.md)."""
    from contract.config import reference_markdown

    print(reference_markdown(), flush=True)
    return 0


def cmd_sessions(args: argparse.Namespace) -> int:
    """How many browsers are logged in; with --end-all, log every one of them out."""
    from contract.store import Store

    settings = get_settings()
    _migrate(settings)
    store = Store(settings.resolved_database_url)
    try:
        if args.end_all:
            print(f"ended {store.end_all_sessions()} login session(s)", flush=True)
        else:
            print(f"{store.count_sessions()} active login session(s)", flush=True)
    finally:
        store.dispose()
    return 0


def cmd_oracle(args: argparse.Namespace, rest: Sequence[str]) -> int:
    from app.oracle import main as oracle_main

    return oracle_main(list(rest))


def cmd_goals(args: argparse.Namespace, rest: Sequence[str]) -> int:
    from sim.goals import main as goals_main

    return goals_main(list(rest))


def _pump(prefix: str, stream, lock: threading.Lock) -> None:  # type: ignore[no-untyped-def]
    for line in iter(stream.readline, ""):
        with lock:
            sys.stdout.write(f"{prefix} | {line}")
            sys.stdout.flush()


def default_learners(cores: int | None = None) -> int:
    """As many learners as the cores allow: one per two cores (a learner trains best on two threads), at least 1."""
    cores = cores if cores is not None else (os.cpu_count() or 1)
    return max(1, cores // 2)


class LearnerRestarts:
    """When to start an exited learner again: at once the first time, then after 1, 2, 4 … 30 s while it keeps
    exiting within a minute of its start (a learner that cannot start is not restarted in a tight loop)."""

    def __init__(self) -> None:
        self.pause, self.exited_at, self.started_at = 0.0, None, time.monotonic()

    def due(self) -> bool:
        now = time.monotonic()
        if self.exited_at is None:
            self.exited_at = now
            self.pause = 0.0 if now - self.started_at > 60 else min(max(2 * self.pause, 1.0), 30.0)
        if now - self.exited_at < self.pause:
            return False
        self.exited_at, self.started_at = None, now
        return True


ROBOT_LOOK_SECONDS = 1.0
"""How often `raq up` looks for a robot run that waits for its robot's process."""


def _store(settings: Settings):  # type: ignore[no-untyped-def]
    from contract.store import Store

    return Store(settings.resolved_database_url)


def _robots_to_start(store, settings: Settings, *, started: set[str]) -> list[str]:  # type: ignore[no-untyped-def]
    """The robots whose run waits for their own process while none is up, that this `raq up` has not started: a
    robot env allowed here (one registered by a factory function counts; the store away: none)."""
    from contract.envs import env_id_problem
    from robot.base import robot_class

    try:
        waiting = store.envs_awaiting_robot()
    except Exception:  # noqa: BLE001 - the store away: looked at again
        return []
    found = []
    for env_id in waiting:
        if env_id in started or env_id_problem(env_id, allowed_modules=settings.env_modules) is not None:
            continue
        try:
            if robot_class(env_id) is False:
                continue
        except Exception:  # noqa: BLE001, S112 - a module that fails to import: its learner says why
            continue
        found.append(env_id)
    return found


def cmd_up(args: argparse.Namespace) -> int:
    """The web server, N learner workers and the robots of RAQ_ROBOTS, their logs in one terminal; Ctrl-C stops them
    all."""
    settings = get_settings()
    _migrate(settings)
    if args.demo:
        from app.demo import ensure_demo_run

        ensure_demo_run(settings)
    raq = [sys.executable, "-m", "cli"]
    serve = raq + ["serve"] + (["--port", str(args.port)] if args.port else [])
    # Own process groups: a terminal's Ctrl-C reaches only this process, which then asks each child once.
    spawn = {"stdout": subprocess.PIPE, "stderr": subprocess.STDOUT, "text": True, "bufsize": 1, "process_group": 0}
    learners = args.learners if args.learners is not None else default_learners()
    if learners < 1:
        print("raq up: --learners must be at least 1", file=sys.stderr)
        return 2
    children: dict[str, subprocess.Popen] = {}
    learner_env = dict(os.environ)
    if learners > 1 and "OMP_NUM_THREADS" not in learner_env:  # share the cores instead of oversubscribing them
        learner_env["OMP_NUM_THREADS"] = str(max(1, (os.cpu_count() or 1) // learners))
    lock = threading.Lock()

    def start(prefix: str, command: list[str], env: dict[str, str] | None = None) -> None:
        children[prefix] = child = subprocess.Popen(command, env=env, **spawn)
        threading.Thread(target=_pump, args=(prefix, child.stdout, lock), daemon=True).start()

    start("web    ", serve)
    # each robot listed in RAQ_ROBOTS gets its own process: the one that opens its camera and moves its arm
    restarted = {f"robot-{index + 1}": raq + ["robot", env_id] for index, env_id in enumerate(settings.robots)}
    learner_names = ["learner" if learners == 1 else f"learn-{index + 1}" for index in range(learners)]
    restarted.update({prefix: raq + ["learn"] for prefix in learner_names})
    for prefix, command in restarted.items():
        start(prefix, command, learner_env)
    port = args.port or settings.port
    robots = f" and {len(settings.robots)} robot(s)" if settings.robots else ""
    print(
        f"raq up: web on http://{settings.host}:{port}, {learners} learner(s){robots}  (Ctrl-C stops all)", flush=True
    )

    stopping = threading.Event()

    def _stop(signum: int, _frame: object) -> None:
        stopping.set()

    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    code = 0
    restarts = {prefix: LearnerRestarts() for prefix in restarted}
    store, looked_at = None, 0.0
    while not stopping.is_set():
        if time.monotonic() - looked_at >= ROBOT_LOOK_SECONDS:  # a robot run waiting for its robot's process
            looked_at = time.monotonic()
            store = store or _store(settings)
            for env_id in _robots_to_start(store, settings, started={command[-1] for command in restarted.values()}):
                prefix = f"robot-{sum(name.startswith('robot-') for name in restarted) + 1}"
                print(f"raq up: a run waits for robot {env_id}; starting its process here", flush=True)
                restarted[prefix], restarts[prefix] = raq + ["robot", env_id], LearnerRestarts()
                start(prefix, restarted[prefix], learner_env)
        web = children["web    "]
        if web.poll() is not None:
            code = web.returncode or 1
            print(f"raq up: web exited with code {web.returncode}; stopping the learners", flush=True)
            break
        for prefix, command in restarted.items():
            child = children[prefix]
            if child.poll() is not None and restarts[prefix].due():
                print(f"raq up: {prefix} exited with code {child.returncode}; starting it again", flush=True)
                start(prefix, command, learner_env)
        time.sleep(0.2)
    for child in children.values():
        if child.poll() is None:
            child.send_signal(signal.SIGINT)
    deadline = time.monotonic() + 30
    for child in children.values():
        try:
            child.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
    print("raq up: stopped", flush=True)
    return code


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="raq", description=__doc__)
    commands = parser.add_subparsers(dest="command", required=True)

    serve = commands.add_parser("serve", help="run the web server (UI and REST API)")
    serve.add_argument("--host", default=None, help="default: RAQ_HOST or 127.0.0.1")
    serve.add_argument("--port", type=int, default=None, help="default: RAQ_PORT or 8000")
    serve.add_argument("--log-level", default="info")
    serve.add_argument(
        "--workers", type=int, default=1, help="server processes (default 1); more serve more labellers at once"
    )
    serve.set_defaults(handler=cmd_serve)

    learn = commands.add_parser("learn", help="run a learner worker that claims queued runs and trains them")
    learn.add_argument("--name", default=None, help="worker name (default: host:pid)")
    learn.add_argument("--once", action="store_true", help="train at most one run, then exit")
    learn.set_defaults(handler=cmd_learn)

    robot = commands.add_parser(
        "robot", help="own a robot on this host: its camera for the pages, its arm for the runs that train on it"
    )
    robot.add_argument("env_id", help="the robot's env id (module:EnvId, its module in RAQ_ENV_MODULES)")
    robot.set_defaults(handler=cmd_robot)

    actor = commands.add_parser(
        "actor", help="drive one run's robot from this host while its learner trains elsewhere (remote_actor)"
    )
    actor.add_argument("--run", type=int, required=True, help="the run's id")
    actor.set_defaults(handler=cmd_actor)

    up = commands.add_parser("up", help="web server and learner workers together")
    up.add_argument("--port", type=int, default=None)
    up.add_argument(
        "--learners", type=int, default=None,
        help=f"learner workers, each training one run at a time (default: one per two cores: {default_learners()})",
    )  # fmt: skip
    up.add_argument("--demo", action="store_true", help="when there are no runs, start a demo pusher run")
    up.set_defaults(handler=cmd_up)

    migrate = commands.add_parser("migrate", help="apply database migrations")
    migrate.set_defaults(handler=cmd_migrate)

    config = commands.add_parser("config", help="print every field of a run's configuration, with its default")
    config.set_defaults(handler=cmd_config)

    sessions = commands.add_parser("sessions", help="count browser login sessions, or end them all")
    sessions.add_argument("--end-all", action="store_true", help="log every browser out now")
    sessions.set_defaults(handler=cmd_sessions)

    oracle = commands.add_parser("oracle", help="answer queries from simulated ground truth (REST API)", add_help=False)
    oracle.set_defaults(passthrough=cmd_oracle)
    goals = commands.add_parser("goals", help="render goal example PNGs of a simulated task", add_help=False)
    goals.set_defaults(passthrough=cmd_goals)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    os.environ.setdefault("MUJOCO_GL", "egl")
    parser = build_parser()
    args, rest = parser.parse_known_args(argv)
    if hasattr(args, "passthrough"):
        return args.passthrough(args, rest)
    if rest:
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    return args.handler(args)
