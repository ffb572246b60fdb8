"""A whole learning run through the real store, the real server and `raq oracle` answering queries.

    python bench/learn.py --task pusher --algorithm vice_raq --seed 0 --total-steps 100000
    python bench/learn.py --task door --task-settings --seed 1 --total-steps 200000 --threads 1

Writes <out>/curve.csv and <out>/curve.png (eval success rate and queries against env steps) and prints
a summary line: env steps to first reach 90% eval success, queries asked, wall time, updates/s.
"""

import argparse
import contextlib
import csv
import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from app.demo import add_simulated_goal_set  # noqa: E402
from app.migrate import upgrade  # noqa: E402
from bench.plot import line_plot  # noqa: E402
from bench.processes import stop_all  # noqa: E402
from contract.config import TrainConfig  # noqa: E402
from contract.envs import SIM_TASK_SETTINGS  # noqa: E402
from contract.store import Conflict, RunStatus, Store  # noqa: E402
from sim import TASKS  # noqa: E402

CURVE_METRICS = [
    "eval/success_rate", "eval/return", "queries/asked", "queries/answered", "queries/yes",
    "reward/acc_goal", "reward/acc_replay", "perf/updates_per_second", "perf/steps_per_second",
]  # fmt: skip


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def parse_overrides(pairs: list[str]) -> dict[str, object]:
    overrides: dict[str, object] = {}
    for pair in pairs:
        key, _, raw = pair.partition("=")
        try:
            overrides[key] = json.loads(raw)
        except json.JSONDecodeError:
            overrides[key] = raw
    return overrides


def wait_for_health(url: str, timeout: float = 60) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            urllib.request.urlopen(f"{url}/health", timeout=2).read()
            return
        except OSError:
            time.sleep(0.5)
    raise SystemExit(f"server at {url} did not answer /health")


def curve_rows(store: Store, run_id: int) -> list[dict[str, float]]:
    by_step: dict[int, dict[str, float]] = {}
    for metric in store.metrics(run_id=run_id, names=CURVE_METRICS):
        by_step.setdefault(metric.step, {"step": metric.step})[metric.name] = metric.value
    rows, last = [], {}
    for step in sorted(by_step):
        last.update(by_step[step])
        rows.append(dict(last))
    return rows


def first_step_reaching(rows: list[dict[str, float]], name: str, threshold: float) -> int | None:
    return next((int(row["step"]) for row in rows if row.get(name, -1) >= threshold), None)


def reached_success(store: Store, run_id: int, rate: float, after_step: int = 0) -> bool:
    metrics = store.metrics(run_id=run_id, since_step=after_step, names=["eval/success_rate"])
    return any(m.value >= rate for m in metrics)


def watch(
    store: Store, run_id: int, learner: subprocess.Popen, args: argparse.Namespace, started: float, resumed_at: int
) -> str | None:
    """Report progress every minute until the learner ends or a stop condition holds (then stop the run and say
    which); None when the learner ended by itself."""
    next_report = time.monotonic() + 60
    while learner.poll() is None:
        stop_reason = None
        if time.monotonic() - started > args.max_minutes * 60:
            stop_reason = f"time limit of {args.max_minutes} min reached"
        elif args.stop_at_success is not None and reached_success(
            store, run_id, args.stop_at_success, after_step=resumed_at
        ):
            stop_reason = f"eval success rate reached {args.stop_at_success}"
        elif args.until_step is not None and int(store.get_run(run_id=run_id).step or 0) >= args.until_step:
            stop_reason = f"env step {args.until_step} reached"
        if stop_reason:
            print(f"{stop_reason}: stopping the run", flush=True)
            with contextlib.suppress(Conflict):  # (the run ended by itself meanwhile: at its last step)
                store.request_stop(run_id=run_id)
            learner.wait(timeout=300)
            return stop_reason
        if time.monotonic() >= next_report:
            rows = curve_rows(store, run_id)
            last = rows[-1] if rows else {}
            print(
                f"[{(time.monotonic() - started) / 60:5.1f} min] step {store.get_run(run_id=run_id).step:>7,}"
                f"  success {last.get('eval/success_rate', float('nan')):.2f}"
                f"  queries {last.get('queries/asked', 0):.0f} (yes {last.get('queries/yes', 0):.0f})"
                f"  updates/s {last.get('perf/updates_per_second', float('nan')):.1f}",
                flush=True,
            )
            next_report = time.monotonic() + 60
        with contextlib.suppress(subprocess.TimeoutExpired):  # every 2 s, and at once when the learner ends
            learner.wait(timeout=2)
    return None


def _interrupt(signum: int, _frame: object) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def write_report(
    store: Store, run_id: int, out: Path, name: str, *, stop_reason: str | None, threads: int | None,
    wall_minutes: float | None,
) -> dict[str, object]:  # fmt: skip
    """<out>/curve.csv, curve.png and summary.json of the run, from its store; prints the SUMMARY line."""
    rows = curve_rows(store, run_id)
    final = store.get_run(run_id=run_id)
    with (out / "curve.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=["step", *CURVE_METRICS])
        writer.writeheader()
        writer.writerows(rows)
    success = [(m.step, m.value) for m in store.metrics(run_id=run_id, names=["eval/success_rate"])]
    budget = int(final.config.get("query_budget", TrainConfig.query_budget))  # (the run's own, as created)
    queries = [(row["step"], row.get("queries/asked", 0) / max(1, budget)) for row in rows]
    line_plot(
        out / "curve.png",
        {"eval success rate": success, f"queries asked / {budget}": queries},
        title=f"{name}: {final.status}",
        y_range=(0.0, 1.0),
    )
    reached = first_step_reaching(rows, "eval/success_rate", 0.9)
    counts = store.query_counts(run_id=run_id)
    updates = [row["perf/updates_per_second"] for row in rows if "perf/updates_per_second" in row]
    summary = {
        "run": name,
        "status": final.status,
        "stopped_because": stop_reason,
        "learner_threads": threads,
        "reason": final.status_reason,
        "env_steps": final.step,
        "steps_to_90pct_success": reached,
        "final_success_rate": success[-1][1] if success else None,
        "queries_asked": counts["asked"],
        "queries_yes": counts["yes"],
        "wall_minutes": None if wall_minutes is None else round(wall_minutes, 1),
        "updates_per_second": round(sum(updates) / len(updates), 2) if updates else None,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print("SUMMARY " + json.dumps(summary), flush=True)
    return summary


def report_only(out: Path, name: str, *, threads: int | None) -> int:
    """--report: the run's curve and summary as the end of a run writes them; the wall time is its learner's, from
    its start to its last heartbeat (a resumed run: since the latest start)."""
    store = Store(f"sqlite:///{(out / 'data' / 'raq.sqlite3').resolve()}")
    run = store.list_runs()[0]
    last = run.finished_at or run.heartbeat_at
    wall_minutes = (last - run.started_at).total_seconds() / 60 if run.started_at and last else None
    summary = write_report(store, run.id, out, name, stop_reason="report", threads=threads, wall_minutes=wall_minutes)
    store.dispose()
    return 1 if summary["status"] == "failed" else 0


def main() -> int:
    signal.signal(signal.SIGTERM, _interrupt)  # background jobs ignore SIGINT: let SIGTERM stop the run cleanly
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", choices=sorted(TASKS), default="pusher")
    parser.add_argument("--algorithm", default="vice_raq")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--total-steps", type=int, default=None,
        help="env steps of the run (default 100,000); with --resume, a larger total trains a stopped run further",
    )  # fmt: skip
    parser.add_argument(
        "--task-settings", action="store_true",
        help="start from the task preset (sim.PRESETS, the New "
        "run form's); --query-every, --query-budget and --set still win",
    )  # fmt: skip
    parser.add_argument("--query-every", type=int, default=None, help="default: TrainConfig's (5000)")
    parser.add_argument("--query-budget", type=int, default=None, help="default: TrainConfig's (20)")
    parser.add_argument("--goals", type=int, default=10, help="goal examples from `raq goals`")
    parser.add_argument("--noise", type=float, default=0.0, help="oracle answer noise")
    parser.add_argument("--set", nargs="*", default=[], metavar="FIELD=VALUE", help="other TrainConfig fields")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--max-minutes", type=float, default=180)
    parser.add_argument(
        "--stop-at-success", type=float, default=None, metavar="RATE",
        help="stop the run at the first evaluation with at least this success rate (saves the rest of the run)",
    )  # fmt: skip
    parser.add_argument(
        "--threads", type=int, default=None,
        help="torch threads of the learner (OMP_NUM_THREADS); 1 lets two runs share 2 cores without oversubscription",
    )  # fmt: skip
    parser.add_argument(
        "--resume", action="store_true",
        help="continue the stopped run in --out from its checkpoint, to a larger --total-steps if given (wall time "
        "adds to the earlier summary's)",
    )  # fmt: skip
    parser.add_argument("--until-step", type=int, default=None, help="stop the run once it reaches this env step")
    parser.add_argument(
        "--report", action="store_true",
        help="only write the curve and summary of the run in --out from its database (a run whose script was killed)",
    )  # fmt: skip
    args = parser.parse_args()

    name = f"{args.task}-{args.algorithm}-seed{args.seed}"
    out = args.out or ROOT / "bench" / "out" / name
    out.mkdir(parents=True, exist_ok=True)
    data_dir = out / "data"
    if data_dir.exists() and not (args.resume or args.report):
        raise SystemExit(f"{data_dir} exists: remove it, choose another --out or --resume it")
    if (args.resume or args.report) and not (data_dir / "raq.sqlite3").exists():
        raise SystemExit(f"no run in {out}: no {data_dir / 'raq.sqlite3'}")
    if args.report:
        return report_only(out, name, threads=args.threads)
    fields = dict(SIM_TASK_SETTINGS[TASKS[args.task]].fields) if args.task_settings else {}
    given = {"query_every": args.query_every, "query_budget": args.query_budget}
    fields |= {name: value for name, value in given.items() if value is not None} | parse_overrides(args.set)
    total_steps = args.total_steps or 100_000
    config = TrainConfig(
        env_id=TASKS[args.task], algorithm=args.algorithm, seed=args.seed, total_steps=total_steps, **fields
    )
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    env = {**os.environ, "RAQ_DATA_DIR": str(data_dir), "RAQ_PORT": str(port), "PYTHONUNBUFFERED": "1"}
    if args.threads:
        env["OMP_NUM_THREADS"] = str(args.threads)
    env.pop("RAQ_DATABASE_URL", None)
    env.pop("DATABASE_URL", None)
    database_url = f"sqlite:///{(data_dir / 'raq.sqlite3').resolve()}"
    upgrade(database_url)
    store = Store(database_url)
    earlier_minutes = 0.0
    if args.resume:  # the one run of this --out, as it was stopped, re-queued by an interrupt or left by a kill
        run = store.list_runs()[0]
        if args.total_steps and args.total_steps > max(run.total_steps, run.step or 0):  # trained further
            run = store.continue_run(run_id=run.id, total_steps=args.total_steps)
        elif run.status in (RunStatus.STOPPED, RunStatus.FAILED):
            run = store.resume_run(run_id=run.id)
        # (queued: claimed as it is; starting or training, its learner killed: claimed once its heartbeat is stale)
        earlier = out / "summary.json"  # (absent when the earlier run was killed before writing it)
        earlier_minutes = float(json.loads(earlier.read_text())["wall_minutes"]) if earlier.exists() else 0.0
    else:
        goal_set_id = add_simulated_goal_set(store, task=args.task, name=f"{args.task} goals", count=args.goals)
        run = store.create_run(
            name=name, env_id=config.env_id, algorithm=config.algorithm, config=config.to_dict(), seed=config.seed,
            goal_set_id=goal_set_id, total_steps=config.total_steps,
        )  # fmt: skip
    resumed_at = int(run.step or 0)

    raq = [sys.executable, "-m", "cli"]
    logs = {key: (out / f"{key}.log").open("a" if args.resume else "w") for key in ("serve", "oracle", "learn")}
    serve = subprocess.Popen(
        raq + ["serve", "--port", str(port)], env=env, stdout=logs["serve"], stderr=subprocess.STDOUT
    )
    processes = [serve]
    started = time.monotonic()
    stop_reason: str | None = None
    interrupted = False
    try:
        wait_for_health(url)
        oracle_args = [
            "oracle",
            "--url",
            url,
            "--run",
            str(run.id),
            "--noise",
            str(args.noise),
            "--seed",
            str(args.seed),
        ]
        processes.append(subprocess.Popen(raq + oracle_args, env=env, stdout=logs["oracle"], stderr=subprocess.STDOUT))
        learner = subprocess.Popen(raq + ["learn", "--once"], env=env, stdout=logs["learn"], stderr=subprocess.STDOUT)
        processes.append(learner)
        try:
            stop_reason = watch(store, run.id, learner, args, started, resumed_at)
        except KeyboardInterrupt as interrupt:  # SIGTERM or Ctrl-C: stop the run, then write its curve and summary
            interrupted, stop_reason = True, f"interrupted ({interrupt})"
            print(f"{stop_reason}: stopping the run", flush=True)
            store.request_stop(run_id=run.id)
            learner.wait(timeout=300)
    finally:
        stop_all(processes, signal.SIGINT, timeout=60)
        for log in logs.values():
            log.close()
    wall_seconds = time.monotonic() - started

    summary = write_report(
        store, run.id, out, name, stop_reason=stop_reason, threads=args.threads,
        wall_minutes=earlier_minutes + wall_seconds / 60,
    )  # fmt: skip
    store.dispose()
    return 1 if summary["status"] == "failed" or interrupted else 0  # (stopped at a --stop-at-* condition: 0)


if __name__ == "__main__":
    sys.exit(main())
