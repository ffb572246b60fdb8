"""The learning results in docs/results/: one plot per task and the Markdown tables of docs/results.md.

    .venv/bin/python bench/results.py --tables        # the seeds tables of README.md and docs/results.md, from
                                                      # docs/results/seeds.csv (bench/seeds.py's rows)
    .venv/bin/python bench/results.py --tables --check  # exits 1 when they are not what the CSV gives
    .venv/bin/python bench/results.py                 # writes docs/results/<task>.png, prints the tables
    .venv/bin/python bench/results.py --results DIR   # another folder of bench/learn.py outputs

The seeds tables: per task the last row of each seed of VICE-RAQ in the CSV (bench/seeds.py replaces a row of the
same commit and appends the others), counted against bench/seeds.py's TARGETS: a seed is within the target when
it reached the eval success rate within the env-step budget, asking at most the query budget by then. The noisy
oracle's rows (`bench/seeds.py --noise 0.1 --csv docs/results/seeds-noise.csv`) get their own table.

Every folder `<task>-<method>-seed<N>/` (a CPU run) or `<task>-<method>-seed<N>-gpu/` (a GPU run) is one
`bench/learn.py` run: its `curve.csv` (the run's metrics, a row every 250 env steps) and, where the script wrote
one, its `summary.json`. Per task the target is an eval success rate reached within a number of env steps
(TARGETS). For each run it finds the first evaluation at or above the target within that budget, the queries
asked by then and the wall-clock minutes to it: the run's measured wall time (summary.json) split in proportion
to the time its logged speed (perf/steps_per_second) puts before that step; without a summary, that logged time
alone (it leaves out the start-up, about a minute).

The plot of a task has one panel per method and device, one line per seed, the target as a dashed line.
"""

import argparse
import csv
import json
import re
import statistics
import sys
from dataclasses import dataclass
from pathlib import Path

from PIL import Image, ImageDraw

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.seeds import MEDIAN_TARGETS  # noqa: E402
from bench.seeds import TARGETS as SEED_TARGETS  # noqa: E402

SEEDS_CSV = ROOT / "docs" / "results" / "seeds.csv"
NOISE_CSV = ROOT / "docs" / "results" / "seeds-noise.csv"
TABLE_FILES = {"README.md": ("summary",), "docs/results.md": ("summary", "seeds", "noise")}
"""Which generated tables each file holds, each between <!-- seeds:NAME --> and <!-- /seeds:NAME -->."""

TARGETS: dict[str, tuple[float, int]] = {
    "pusher": (0.9, 30_000),
    "door": (0.9, 200_000),
    "picker": (0.8, 300_000),
}
"""Per task: the eval success rate to reach and the env steps to reach it in."""

METHODS = ("vice_raq", "vice", "raq", "naive_classifier", "sparse")
RUN_NAME = re.compile(r"^(?P<task>[a-z]+)-(?P<method>[a-z_]+)-seed(?P<seed>\d+)(?P<gpu>-gpu)?$")
PALETTE = [
    "#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#7f7f7f",
    "#bcbd22", "#17becf", "#393b79", "#637939", "#8c6d31", "#843c39", "#7b4173", "#3182bd",
]  # fmt: skip


@dataclass
class Run:
    task: str
    method: str
    seed: int
    device: str  # "CPU" or "GPU"
    name: str
    curve: list[tuple[int, float]]  # (env step, eval success rate) at each evaluation
    steps_run: int
    steps_to_target: int | None
    queries: int  # asked by the target's step, else by the end
    queries_yes: int
    minutes: float  # to the target, else the whole run

    @property
    def best(self) -> tuple[float, int]:
        """The best eval success rate within the task's budget and the first step it was reached at."""
        budget = TARGETS[self.task][1]
        within = [(step, value) for step, value in self.curve if step <= budget]
        rate = max((value for _, value in within), default=0.0)
        return rate, next((step for step, value in within if value == rate), 0)

    def best_text(self) -> str:
        rate, at = self.best
        return f"{rate:.0%} at {thousands(at)}" if rate > 0 else "0% at every evaluation"


def read_run(folder: Path) -> Run | None:
    match = RUN_NAME.match(folder.name)
    if match is None or match["task"] not in TARGETS or not (folder / "curve.csv").exists():
        return None
    target, budget = TARGETS[match["task"]]
    rows: dict[int, dict[str, str]] = {}
    with (folder / "curve.csv").open() as handle:
        for row in csv.DictReader(handle):
            rows[int(float(row["step"]))] = row  # a resumed run may log a step twice: the last one counts
    steps = sorted(rows)

    def number(step: int, column: str) -> float | None:
        value = rows[step].get(column)
        return float(value) if value not in (None, "") else None

    curve = [(step, rate) for step in steps if (rate := number(step, "eval/success_rate")) is not None]
    reached = next((step for step, rate in curve if rate >= target - 1e-9 and step <= budget), None)
    until = reached if reached is not None else steps[-1]
    counted = [step for step in steps if step <= until]

    def last(column: str) -> int:
        values = [value for step in counted if (value := number(step, column)) is not None]
        return int(values[-1]) if values else 0

    logged, elapsed, previous = 0.0, 0.0, 0  # seconds of the run's logged speed: in all, and up to `until`
    for step in steps:
        speed = number(step, "perf/steps_per_second")
        if speed:
            logged += (step - previous) / speed
            if step <= until:
                elapsed = logged
        previous = step
    summary = json.loads((folder / "summary.json").read_text()) if (folder / "summary.json").exists() else {}
    wall = summary.get("wall_minutes")
    minutes = wall * elapsed / logged if wall and logged else elapsed / 60
    return Run(
        task=match["task"], method=match["method"], seed=int(match["seed"]), device="GPU" if match["gpu"] else "CPU",
        name=folder.name, curve=curve, steps_run=steps[-1], steps_to_target=reached, queries=last("queries/asked"),
        queries_yes=last("queries/yes"), minutes=minutes,
    )  # fmt: skip


def group_key(run: Run) -> tuple[int, int]:
    return (METHODS.index(run.method) if run.method in METHODS else len(METHODS), run.device == "GPU")


def thousands(step: float) -> str:
    return f"{step / 1000:.0f}K" if step >= 1000 else f"{step:.0f}"


def median(values: list[float]) -> float | None:
    return statistics.median(values) if values else None


def groups_of(runs: list[Run]) -> dict[tuple[str, str], list[Run]]:
    groups: dict[tuple[str, str], list[Run]] = {}
    for run in sorted(runs, key=lambda r: (group_key(r), r.seed)):
        groups.setdefault((run.method, run.device), []).append(run)
    return groups


def summary_table(task: str, runs: list[Run]) -> list[str]:
    target, budget = TARGETS[task]
    lines = [
        "| task | method | device | target | seeds that reached it | median env steps to it | median queries "
        "| median minutes | the others: best eval success within the budget |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for (method, device), members in groups_of(runs).items():
        hit = [run for run in members if run.steps_to_target is not None]
        steps = median([run.steps_to_target for run in hit])
        queries = median([run.queries for run in hit])
        minutes = median([run.minutes for run in hit])
        others = ", ".join(
            f"seed {run.seed}: {run.best_text()}"
            + (f" (stopped at {thousands(run.steps_run)})" if run.steps_run < budget else "")
            for run in members
            if run not in hit
        )
        lines.append(
            f"| {task} | {method} | {device} | {target:.0%} within {thousands(budget)} | {len(hit)} of {len(members)} "
            f"| {thousands(steps) if steps is not None else '-'} | {f'{queries:g}' if queries is not None else '-'} "
            f"| {f'{minutes:.1f}' if minutes is not None else '-'} | {others or '-'} |"
        )
    return lines


def run_table(members: list[Run]) -> list[str]:
    lines = [
        "| seed | first at target | queries (yes) by then | minutes | best eval success within the budget "
        "| env steps run | folder |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for run in members:
        reached = thousands(run.steps_to_target) if run.steps_to_target is not None else "not reached"
        lines.append(
            f"| {run.seed} | {reached} | {run.queries} ({run.queries_yes}) | {run.minutes:.1f} "
            f"| {run.best_text()} | {thousands(run.steps_run)} | `{run.name}/` |"
        )
    return lines


def plot_task(path: Path, task: str, runs: list[Run]) -> None:
    """One panel per method and device, one line per seed."""
    target, budget = TARGETS[task]
    groups = groups_of(runs)
    width, panel, left, right, top, bottom = 1000, 340, 60, 190, 34, 42
    image = Image.new("RGB", (width, panel * len(groups)), "white")
    draw = ImageDraw.Draw(image)
    for index, ((method, device), members) in enumerate(groups.items()):
        y0 = index * panel
        x_max = max(max(run.steps_run for run in members), min(budget, 30_000))
        plot_w, plot_h = width - left - right, panel - top - bottom

        def pixel(x: float, y: float, y0: int = y0, x_max: float = x_max, w: int = plot_w, h: int = plot_h):
            return left + w * x / x_max, y0 + top + h * (1.0 - y)

        draw.rectangle([left, y0 + top, left + plot_w, y0 + top + plot_h], outline="black")
        for tick in range(6):
            px, py = pixel(x_max * tick / 5, tick / 5)
            draw.line([left - 4, py, left, py], fill="black")
            draw.text((left - 34, py - 6), f"{tick * 20}%", fill="black")
            bx, by = pixel(x_max * tick / 5, 0.0)
            draw.line([bx, by, bx, by + 4], fill="black")
            draw.text((bx - 12, by + 8), thousands(x_max * tick / 5), fill="black")
        _, ty = pixel(0, target)
        for x in range(left, left + plot_w, 12):
            draw.line([x, ty, x + 6, ty], fill="#999999")
        if budget < x_max:
            bx, _ = pixel(budget, 0)
            draw.line([bx, y0 + top, bx, y0 + top + plot_h], fill="#999999")
        reached = sum(run.steps_to_target is not None for run in members)
        draw.text(
            (left, y0 + 10),
            f"{task}, {method}, {device}: eval success rate against env steps; {reached} of {len(members)} seeds at "
            f"{target:.0%} within {thousands(budget)} (dashed: the target)",
            fill="black",
        )
        draw.text((left + plot_w / 2 - 30, y0 + panel - 18), "env steps", fill="black")
        for number, run in enumerate(members):
            colour = PALETTE[number % len(PALETTE)]
            points = [pixel(step, rate) for step, rate in run.curve]
            if len(points) > 1:
                draw.line(points, fill=colour, width=2)
            label = f"seed {run.seed}: " + (thousands(run.steps_to_target) if run.steps_to_target else "-")
            draw.text((left + plot_w + 12, y0 + top + 16 * number), label, fill=colour)
    image.save(path)


# ---------------------------------------------------------------------------------------------- seeds tables
def seed_rows(path: Path) -> dict[str, list[dict[str, str]]]:
    """Per task, the last VICE-RAQ row of each seed, by seed."""
    if not path.exists():
        return {}
    last: dict[tuple[str, int], dict[str, str]] = {}
    with path.open() as file:
        for row in csv.DictReader(file):
            if row["algorithm"] == "vice_raq" and row["task"] in SEED_TARGETS:
                last[(row["task"], int(row["seed"]))] = row
    by_task: dict[str, list[dict[str, str]]] = {}
    for (task, _), row in sorted(last.items(), key=lambda item: (list(SEED_TARGETS).index(item[0][0]), item[0][1])):
        by_task.setdefault(task, []).append(row)
    return by_task


def within_target(row: dict[str, str]) -> bool:
    _, budget, max_queries = SEED_TARGETS[row["task"]]
    steps = row["steps_to_target"]
    return steps != "" and int(steps) <= budget and int(row["queries"]) <= max_queries


def target_text(task: str) -> str:
    target, budget, max_queries = SEED_TARGETS[task]
    median = f", median ≤ {thousands(MEDIAN_TARGETS[task])}" if task in MEDIAN_TARGETS else ""
    return f"{target:.0%} within {thousands(budget)}{median}, ≤ {max_queries} queries"


def summary_lines(by_task: dict[str, list[dict[str, str]]]) -> list[str]:
    lines = [
        "| task | target | seeds within it | median env steps to it | median queries (yes) | device | commit |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for task in SEED_TARGETS:
        rows = by_task.get(task, [])
        if not rows:
            lines.append(f"| {task} | {target_text(task)} | not measured | - | - | - | - |")
            continue
        hit = [row for row in rows if within_target(row)]
        steps = median([int(row["steps_to_target"]) for row in hit])
        queries = median([int(row["queries"]) for row in hit])
        yes = median([int(row["queries_yes"]) for row in hit])
        seeds = ", ".join(row["seed"] for row in rows)
        lines.append(
            f"| {task} | {target_text(task)} | {len(hit)} of {len(rows)} (seeds {seeds}) "
            f"| {thousands(steps) if steps is not None else '-'} "
            f"| {f'{queries:g} ({yes:g})' if queries is not None else '-'} "
            f"| {', '.join(sorted({row['device'] for row in rows}))} "
            f"| {', '.join(sorted({row['commit'] for row in rows}))} |"
        )
    return lines


def per_seed_lines(by_task: dict[str, list[dict[str, str]]]) -> list[str]:
    lines = [
        "| task | seed | steps to target | env steps run | queries (yes) | minutes | within the target | device "
        "| commit |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for task, rows in by_task.items():
        for row in rows:
            steps = f"{int(row['steps_to_target']):,}" if row["steps_to_target"] else "not reached"
            lines.append(
                f"| {task} | {row['seed']} | {steps} | {int(row['env_steps']):,} "
                f"| {row['queries']} ({row['queries_yes']}) "
                f"| {row['minutes']} | {'yes' if within_target(row) else 'no'} | {row['device']} | {row['commit']} |"
            )
    if len(lines) == 2:
        lines.append("| - | - | - | - | - | - | - | - | - |")
    return lines


def seeds_tables() -> dict[str, list[str]]:
    """Each generated table's lines, by name."""
    rows, noisy = seed_rows(SEEDS_CSV), seed_rows(NOISE_CSV)
    return {"summary": summary_lines(rows), "seeds": per_seed_lines(rows), "noise": per_seed_lines(noisy)}


def with_tables(text: str, tables: dict[str, list[str]], names: tuple[str, ...], path: str) -> str:
    for name in names:
        start, end = f"<!-- seeds:{name} -->", f"<!-- /seeds:{name} -->"
        if start not in text or end not in text:
            raise SystemExit(f"{path}: no {start} ... {end}")
        before, rest = text.split(start, 1)
        _, after = rest.split(end, 1)
        text = before + start + "\n" + "\n".join(tables[name]) + "\n" + end + after
    return text


def write_tables(*, check: bool) -> int:
    tables, stale = seeds_tables(), []
    for name, names in TABLE_FILES.items():
        path = ROOT / name
        text = path.read_text()
        fresh = with_tables(text, tables, names, name)
        if fresh != text:
            stale.append(name)
            if not check:
                path.write_text(fresh)
    if check and stale:
        print(f"not what {SEEDS_CSV.relative_to(ROOT)} gives: {', '.join(stale)} (run bench/results.py --tables)")
        return 1
    print(f"{'stale' if check else 'rewritten'}: {', '.join(stale) or 'none'}")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--results", type=Path, default=ROOT / "docs" / "results")
    parser.add_argument("--no-plots", action="store_true")
    parser.add_argument("--tables", action="store_true", help="rewrite the seeds tables from docs/results/seeds.csv")
    parser.add_argument("--check", action="store_true", help="with --tables: only say whether they are stale")
    args = parser.parse_args()
    if args.tables:
        return write_tables(check=args.check)
    runs = [run for folder in sorted(args.results.iterdir()) if folder.is_dir() and (run := read_run(folder))]
    skipped = [folder.name for folder in sorted(args.results.iterdir()) if folder.is_dir() and read_run(folder) is None]
    if skipped:
        print(f"not a run folder (<task>-<method>-seed<N>[-gpu]/, curve.csv): {', '.join(skipped)}", file=sys.stderr)
    for task in TARGETS:
        members = [run for run in runs if run.task == task]
        if not members:
            continue
        print(f"## {task}\n")
        print("\n".join(summary_table(task, members)))
        for (method, device), group in groups_of(members).items():
            print(f"\n### {task}-{method}-{device.lower()}\n")
            print("\n".join(run_table(group)))
        print()
        if not args.no_plots:
            plot_task(args.results / f"{task}.png", task, members)
            print(f"(plot: {args.results / f'{task}.png'})\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
