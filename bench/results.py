"""The learning results in docs/results/: the Markdown tables of the README and docs/results.md, and the plot of
the paper's comparison.

    .venv/bin/python bench/results.py                 # rewrites the tables and docs/results/pusher-methods.png
    .venv/bin/python bench/results.py --tables        # only the tables
    .venv/bin/python bench/results.py --tables --check  # exits 1 when they are not what docs/results/ gives

The seeds tables: per task the last row of each seed of VICE-RAQ in docs/results/seeds.csv (bench/seeds.py
replaces a row of the same commit and appends the others), counted against bench/seeds.py's TARGETS: a seed is
within the target when it reached the eval success rate within the env-step budget, asking at most the query
budget by then. The noisy oracle's rows (`bench/seeds.py --noise 0.1 --csv docs/results/seeds-noise.csv`) get
their own table.

The comparison: every folder of docs/results/compare/ is one bench/learn.py run, `pusher-<method>-seed<N>/`
(its curve.csv and summary.json); bench/compare.py --by-method makes its table and its plot of each method's
mean eval success with the spread over seeds, up to COMPARE_UNTIL env steps.
"""

import argparse
import csv
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.compare import method_table, runs_by_method  # noqa: E402
from bench.plot import line_plot  # noqa: E402
from bench.seeds import TARGETS as SEED_TARGETS  # noqa: E402

RESULTS = ROOT / "docs" / "results"
SEEDS_CSV = RESULTS / "seeds.csv"
NOISE_CSV = RESULTS / "seeds-noise.csv"
COMPARE_RUNS = RESULTS / "compare"
COMPARE_PLOT = RESULTS / "pusher-methods.png"
COMPARE_UNTIL = 15_000
"""The comparison's horizon: the env steps every run of every method reached."""
TABLE_FILES = {"README.md": ("summary",), "docs/results.md": ("summary", "seeds", "noise", "compare")}
"""Which generated tables each file holds, each between <!-- results:NAME --> and <!-- /results:NAME -->."""


def thousands(step: float) -> str:
    return f"{step / 1000:.0f}K" if step >= 1000 else f"{step:.0f}"


def median(values: list[float]) -> float | None:
    return statistics.median(values) if values else None


def comparison() -> tuple[list[str], dict[str, list], dict[str, list]]:
    """The comparison's table, and each method's mean curve and spread, from docs/results/compare/."""
    folders = sorted(folder for folder in COMPARE_RUNS.iterdir() if folder.is_dir()) if COMPARE_RUNS.exists() else []
    return method_table(runs_by_method(folders, COMPARE_UNTIL))


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
    steps = row["steps_to_target"]
    return SEED_TARGETS[row["task"]].met_by(int(steps) if steps else None, int(row["queries"]))


def target_text(task: str) -> str:
    target, budget, max_queries, median_steps = SEED_TARGETS[task]
    median = f", median ≤ {thousands(median_steps)}" if median_steps else ""
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


def generated_tables() -> dict[str, list[str]]:
    """Each generated table's lines, by name."""
    rows, noisy = seed_rows(SEEDS_CSV), seed_rows(NOISE_CSV)
    compared, _, _ = comparison()
    return {
        "summary": summary_lines(rows), "seeds": per_seed_lines(rows), "noise": per_seed_lines(noisy),
        "compare": compared,
    }  # fmt: skip


def with_tables(text: str, tables: dict[str, list[str]], names: tuple[str, ...], path: str) -> str:
    for name in names:
        start, end = f"<!-- results:{name} -->", f"<!-- /results:{name} -->"
        if start not in text or end not in text:
            raise SystemExit(f"{path}: no {start} ... {end}")
        before, rest = text.split(start, 1)
        _, after = rest.split(end, 1)
        text = before + start + "\n" + "\n".join(tables[name]) + "\n" + end + after
    return text


def write_tables(*, check: bool) -> int:
    tables, stale = generated_tables(), []
    for name, names in TABLE_FILES.items():
        path = ROOT / name
        text = path.read_text()
        fresh = with_tables(text, tables, names, name)
        if fresh != text:
            stale.append(name)
            if not check:
                path.write_text(fresh)
    if check and stale:
        print(f"not what {RESULTS.relative_to(ROOT)}/ gives: {', '.join(stale)} (run bench/results.py --tables)")
        return 1
    print(f"{'stale' if check else 'rewritten'}: {', '.join(stale) or 'none'}")
    return 0


def plot_comparison() -> None:
    _, series, bands = comparison()
    title = "pusher: eval success, mean and min-max over seeds 0-2, per reward method"
    line_plot(COMPARE_PLOT, series, title=title, y_range=(0.0, 1.0), bands=bands)
    print(f"plot: {COMPARE_PLOT.relative_to(ROOT)}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tables", action="store_true", help="only the tables, not the plot")
    parser.add_argument("--check", action="store_true", help="with --tables: only say whether they are stale")
    args = parser.parse_args()
    if not args.tables:
        plot_comparison()
    return write_tables(check=args.check)


if __name__ == "__main__":
    sys.exit(main())
