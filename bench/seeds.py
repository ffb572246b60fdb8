"""Several seeds of one task side by side, each stopped at its target or its budget, and one table of them all.

    python bench/seeds.py --task door --seeds 0-4 --parallel 2
    python bench/seeds.py --task pusher --seeds 0-2 --set updates_per_step=1 --out bench/out/u1 --csv bench/out/u1.csv
    python bench/seeds.py --task pusher --seeds 0-14 --parallel 15 --set device=cuda replay_pipeline=device

Each seed is a whole `bench/learn.py` run (its own server, `raq oracle` and learner on SQLite) in
<out>/<task>-<algorithm>-seed<N>/. Run it again and every seed that is neither at its target nor at its budget
is resumed from its checkpoint; those that are, are only reported. It prints one table (seed, steps to target,
queries, yes, minutes), draws every seed's eval success in <out>/<task>-<algorithm>-seeds.png, and writes each
seed's row into the CSV (a row of the same task, algorithm, seed and commit is replaced), with what the seed's run
cost the person (contract.effort's EFFORT_COLUMNS, read from the seed's own store; rows written before these
columns existed keep them empty).
"""

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import NamedTuple

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.plot import line_plot  # noqa: E402
from contract.effort import EFFORT_COLUMNS, run_effort  # noqa: E402
from contract.store import Store  # noqa: E402


class Target(NamedTuple):
    """What the seeds of a task must reach."""

    success_rate: float
    """the eval success rate to reach"""
    budget: int
    """the env steps to reach it in"""
    max_queries: int
    """the most queries asked by then"""
    median_steps: int | None = None
    """where set: the most env steps the seeds' median may take to it (the paper's robot: 6.2K)"""

    def met_by(self, steps_to_target: int | None, queries: int, *, budget: int | None = None) -> bool:
        """A seed reached the rate within the budget (this target's unless given), asking at most max_queries."""
        within = steps_to_target is not None and steps_to_target <= (budget or self.budget)
        return within and queries <= self.max_queries


TARGETS: dict[str, Target] = {
    "pusher": Target(0.9, 20_000, 25, median_steps=12_000),
    "door": Target(0.9, 100_000, 50),
    "picker": Target(0.8, 100_000, 50),
    "bookshelf": Target(0.9, 15_000, 20),
    "draping": Target(0.9, 15_000, 20),
}
CSV_COLUMNS = [
    "task", "algorithm", "seed", "target", "steps_to_target", "env_steps", "queries", "queries_yes", "minutes",
    "device", "commit", *EFFORT_COLUMNS,
]  # fmt: skip
"""The CSV's columns: the effort's last, so rows written before they existed read as they were."""


@dataclass
class SeedResult:
    """One seed's row: queries and yes answers counted by the step the target was reached, else by the end."""

    task: str
    algorithm: str
    seed: int
    target: float
    steps_to_target: int | None
    env_steps: int
    queries: int
    queries_yes: int
    minutes: float
    device: str
    commit: str
    effort: dict[str, int | float | str]
    """EFFORT_COLUMNS' figures of the seed's run ("" each when its store holds no run)."""


def parse_seeds(text: str) -> list[int]:
    """ "0-4" or "0,2,5" or "0-2,7"."""
    seeds: list[int] = []
    for part in text.split(","):
        first, _, last = part.strip().partition("-")
        seeds.extend(range(int(first), int(last or first) + 1))
    return seeds


def read_curve(folder: Path) -> list[dict[str, float]]:
    with (folder / "curve.csv").open() as file:
        return [{key: float(value) for key, value in row.items() if value != ""} for row in csv.DictReader(file)]


def seed_result(folder: Path, *, task: str, algorithm: str, seed: int, target: float, device: str) -> SeedResult:
    curve = read_curve(folder)
    summary = json.loads((folder / "summary.json").read_text())
    reached = next((row for row in curve if row.get("eval/success_rate", -1.0) >= target), None)
    counted = reached or (curve[-1] if curve else {})
    return SeedResult(
        task=task, algorithm=algorithm, seed=seed, target=target,
        steps_to_target=int(reached["step"]) if reached else None, env_steps=int(summary["env_steps"]),
        queries=int(counted.get("queries/asked", 0)), queries_yes=int(counted.get("queries/yes", 0)),
        minutes=round(float(summary["wall_minutes"]), 1), device=device, commit=current_commit(),
        effort=seed_effort(folder),
    )  # fmt: skip


def seed_effort(folder: Path) -> dict[str, int | float | str]:
    """What the seed's run cost the person, from the seed's own store (its answers and scene resets)."""
    database = folder / "data" / "raq.sqlite3"
    if not database.exists():
        return dict.fromkeys(EFFORT_COLUMNS, "")
    store = Store(f"sqlite:///{database.resolve()}")
    try:
        runs = store.list_runs()
        return run_effort(store, runs[0].id).columns() if runs else dict.fromkeys(EFFORT_COLUMNS, "")
    finally:
        store.dispose()


def current_commit() -> str:
    done = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    return done.stdout.strip() or "unknown"


def finished(folder: Path, *, target: float, budget: int) -> bool:
    """The seed's run reached its target or its budget (or ended for good)."""
    summary_path = folder / "summary.json"
    if not summary_path.exists():
        return False
    summary = json.loads(summary_path.read_text())
    if summary["status"] == "failed" or summary["env_steps"] >= budget:  # (a finished run within budget goes on)
        return True
    return any(row.get("eval/success_rate", -1.0) >= target for row in read_curve(folder))


def learn_command(args: argparse.Namespace, seed: int, folder: Path, target: float, budget: int) -> list[str]:
    command = [
        sys.executable, str(ROOT / "bench" / "learn.py"), "--task", args.task, "--algorithm", args.algorithm,
        "--task-settings", "--seed", str(seed), "--total-steps", str(budget), "--stop-at-success", str(target),
        "--goals", str(args.goals), "--noise", str(args.noise), "--out", str(folder), "--max-minutes",
        str(args.max_minutes),
    ]  # fmt: skip
    if args.threads:
        command += ["--threads", str(args.threads)]
    if args.set:
        command += ["--set", *args.set]
    if (folder / "data" / "raq.sqlite3").exists():
        command.append("--resume")
    return command


def run_seeds(args: argparse.Namespace, seeds: list[int], target: float, budget: int) -> None:
    """Start up to --parallel seeds at once until every seed is at its target or budget."""
    waiting = [seed for seed in seeds if not finished(folder_of(args, seed), target=target, budget=budget)]
    running: dict[int, subprocess.Popen] = {}
    while waiting or running:
        while waiting and len(running) < args.parallel:
            seed = waiting.pop(0)
            folder = folder_of(args, seed)
            folder.mkdir(parents=True, exist_ok=True)
            log = (folder / "seeds.log").open("a")
            running[seed] = subprocess.Popen(
                learn_command(args, seed, folder, target, budget), stdout=log, stderr=subprocess.STDOUT,
                env={**os.environ, "PYTHONPATH": str(ROOT)},
            )  # fmt: skip
            print(f"seed {seed}: started in {folder}", flush=True)
        deadline = time.monotonic() + 5  # look again in 5 s, or as soon as a seed's run ends
        while time.monotonic() < deadline and all(process.poll() is None for process in running.values()):
            time.sleep(0.1)
        for seed, process in list(running.items()):
            if process.poll() is not None:
                del running[seed]
                print(f"seed {seed}: learn.py exited with {process.returncode}", flush=True)


def folder_of(args: argparse.Namespace, seed: int) -> Path:
    return args.out / f"{args.task}-{args.algorithm}-seed{seed}"


def write_csv(path: Path, results: list[SeedResult]) -> None:
    rows: list[dict[str, str]] = []
    if path.exists():
        with path.open() as file:
            rows = list(csv.DictReader(file))
    fresh = {(r.task, r.algorithm, str(r.seed), r.commit) for r in results}
    rows = [row for row in rows if (row["task"], row["algorithm"], row["seed"], row["commit"]) not in fresh]
    for result in results:
        values = {**asdict(result), **result.effort}
        values["steps_to_target"] = "" if result.steps_to_target is None else result.steps_to_target
        rows.append({column: str(values[column]) for column in CSV_COLUMNS})
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=CSV_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)


def report(args: argparse.Namespace, seeds: list[int], target: float, budget: int, max_queries: int) -> int:
    device = next((value.partition("=")[2] for value in args.set or [] if value.startswith("device=")), "cpu")
    results, series = [], {}
    for seed in seeds:
        folder = folder_of(args, seed)
        if not (folder / "summary.json").exists():
            print(f"seed {seed}: no summary in {folder}")
            continue
        result = seed_result(folder, task=args.task, algorithm=args.algorithm, seed=seed, target=target, device=device)
        results.append(result)
        series[f"seed {seed}"] = [
            (row["step"], row["eval/success_rate"]) for row in read_curve(folder) if "eval/success_rate" in row
        ]
    print(f"\n{args.task}, {args.algorithm}: target {target:.0%} within {budget:,} env steps, at most {max_queries} "
          "queries")  # fmt: skip
    print("| seed | steps to target | queries | yes | minutes |\n| --- | --- | --- | --- | --- |")
    for result in results:
        steps = f"{result.steps_to_target:,}" if result.steps_to_target else f"not reached ({result.env_steps:,})"
        print(f"| {result.seed} | {steps} | {result.queries} | {result.queries_yes} | {result.minutes} |")
    met = [r for r in results if TARGETS[args.task].met_by(r.steps_to_target, r.queries, budget=budget)]
    reached = [r.steps_to_target for r in results if r.steps_to_target is not None]
    median = f", median {statistics.median(reached):,.0f} env steps" if reached else ""
    if reached and TARGETS[args.task].median_steps:
        median += f" (its target: at most {TARGETS[args.task].median_steps:,})"
    print(f"{len(met)} of {len(results)} seeds within the target{median}")
    if series:
        plot = args.out / f"{args.task}-{args.algorithm}-seeds.png"
        line_plot(plot, series, title=f"{args.task}, {args.algorithm}: eval success per seed", y_range=(0.0, 1.0))
        print(f"plot: {plot}")
    write_csv(args.csv, results)
    print(f"rows: {args.csv}")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", choices=sorted(TARGETS), required=True)
    parser.add_argument("--algorithm", default="vice_raq")
    parser.add_argument("--seeds", default="0-4", help='e.g. "0-4" or "0,2,5"')
    parser.add_argument("--parallel", type=int, default=2, help="seeds run at once")
    parser.add_argument("--threads", type=int, default=None, help="torch threads per learner (default: 1 if parallel)")
    parser.add_argument("--budget", type=int, default=None, help="env steps per seed (default: the task's)")
    parser.add_argument("--goals", type=int, default=10, help="goal examples from `raq goals`")
    parser.add_argument("--noise", type=float, default=0.0, help="share of the oracle's answers that are wrong")
    parser.add_argument("--set", nargs="*", default=[], metavar="FIELD=VALUE", help="TrainConfig fields")
    parser.add_argument("--max-minutes", type=float, default=600.0, help="wall-clock limit per seed")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "results")
    parser.add_argument("--csv", type=Path, default=ROOT / "docs" / "results" / "seeds.csv")
    parser.add_argument("--report", action="store_true", help="only report the seeds' runs in --out")
    args = parser.parse_args()
    if args.threads is None and args.parallel > 1:
        args.threads = 1
    target, default_budget, max_queries, _ = TARGETS[args.task]
    budget = args.budget or default_budget
    seeds = parse_seeds(args.seeds)
    if not args.report:
        run_seeds(args, seeds, target, budget)
    return report(args, seeds, target, budget, max_queries)


if __name__ == "__main__":
    sys.exit(main())
