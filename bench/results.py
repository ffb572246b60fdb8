"""The learning results in docs/results/: the Markdown tables of the README and docs/results.md, and the plot of
the paper's comparison.

    .venv/bin/python bench/results.py                 # rewrites the tables and the plots
    .venv/bin/python bench/results.py --tables        # only the tables
    .venv/bin/python bench/results.py --tables --check  # exits 1 when they are not what docs/results/ gives

The seeds tables: per task the last row of each seed of VICE-RAQ in docs/results/seeds.csv (bench/seeds.py
replaces a row of the same commit and appends the others), counted against bench/seeds.py's TARGETS: a seed is
within the target when it reached the eval success rate within the env-step budget, asking at most the query
budget by then. The noisy oracle's rows (`bench/seeds.py --noise 0.1 --csv docs/results/seeds-noise.csv`) get
their own table.

The stand-in robot's table and plot: each row of docs/results/robot.csv (bench/robot_standin.py, one per seed,
preset and help) against that bench's TARGETS, and each seed's evaluations from docs/results/robot/<preset>[-<help>]-
seed<N>.json.

The comparisons: every folder of docs/results/compare/ is one bench/learn.py run, `<task>-<method>-seed<N>/` (its
curve.csv and summary.json); bench/compare.py --by-method makes each COMPARED_TASKS task's table and its plot of
each method's mean eval success with the spread over seeds, up to COMPARE_UNTIL env steps.
"""

import argparse
import csv
import io
import json
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from PIL import Image  # noqa: E402

from bench.compare import method_table, runs_by_method  # noqa: E402
from bench.plot import line_plot  # noqa: E402
from bench.robot_standin import HELP_KINDS  # noqa: E402
from bench.robot_standin import TARGET_RATE as ROBOT_RATE  # noqa: E402
from bench.robot_standin import TARGETS as ROBOT_TARGETS  # noqa: E402
from bench.seeds import TARGETS as SEED_TARGETS  # noqa: E402

RESULTS = ROOT / "docs" / "results"
SEEDS_CSV = RESULTS / "seeds.csv"
NOISE_CSV = RESULTS / "seeds-noise.csv"
COMPARE_RUNS = RESULTS / "compare"
COMPARED_TASKS = ("pusher", "bookshelf", "draping")
"""The tasks whose reward methods are compared, each in its own table (results:compare-<task>) and plot."""
COMPARE_UNTIL = 15_000
"""The comparison's horizon: the env steps every run of every method reached."""
ROBOT_CSV = RESULTS / "robot.csv"
ROBOT_FIGURES = RESULTS / "robot"
ROBOT_PLOT = RESULTS / "robot-standin-seeds.png"
TABLE_FILES = {
    "README.md": ("summary",),
    "docs/results.md": ("summary", "seeds", "noise", "robot", *(f"compare-{task}" for task in COMPARED_TASKS)),
}
"""Which generated tables each file holds, each between <!-- results:NAME --> and <!-- /results:NAME -->."""


def thousands(step: float) -> str:
    return f"{round(step / 1000, 1):g}K" if step >= 1000 else f"{step:.0f}"


def median(values: list[float]) -> float | None:
    return statistics.median(values) if values else None


def comparison(task: str) -> tuple[list[str], dict[str, list], dict[str, list]]:
    """A task's comparison table, and each method's mean curve and spread, from docs/results/compare/<task>-*."""
    folders = sorted(COMPARE_RUNS.glob(f"{task}-*-seed*")) if COMPARE_RUNS.exists() else []
    return method_table(runs_by_method([folder for folder in folders if folder.is_dir()], COMPARE_UNTIL))


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


def summary_lines(
    by_task: dict[str, list[dict[str, str]]], robot: dict[str, list[dict[str, str]]] | None = None
) -> list[str]:
    """Per task, its seeds against the target; then per robot preset, the stand-in's seeds (robot_rows)."""
    lines = [
        "| task | target | seeds within it | median env steps to it | median queries (yes) | person minutes "
        "(median) | device | commit |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for task in SEED_TARGETS:
        rows = by_task.get(task, [])
        if not rows:
            lines.append(f"| {task} | {target_text(task)} | not measured | - | - | - | - | - |")
            continue
        hit = [row for row in rows if within_target(row)]
        steps = median([int(row["steps_to_target"]) for row in hit])
        queries = median([int(row["queries"]) for row in hit])
        yes = median([int(row["queries_yes"]) for row in hit])
        seeds = ", ".join(row["seed"] for row in rows)
        lines.append(
            f"| {task} | {target_text(task)} | {len(hit)} of {len(rows)} (seeds {seeds}) "
            f"| {thousands(steps) if steps is not None else '-'} "
            f"| {f'{queries:g} ({yes:g})' if queries is not None else '-'} | {person_minutes(rows)} "
            f"| {', '.join(sorted({row['device'] for row in rows}))} "
            f"| {', '.join(sorted({row['commit'] for row in rows}))} |"
        )
    for group, rows in (robot or {}).items():
        preset, helped = group.split(", ")
        hit = [row for row in rows if robot_within(row)]
        steps = median([int(row["steps_to_target"]) for row in hit])
        queries = median([int(row["queries"]) for row in hit])
        hands = "" if helped == "none" else f", a person's {helped}"
        lines.append(
            f"| pusher stand-in, 5 Hz, {preset}{hands} | {robot_target_text(preset)} "
            f"| {len(hit)} of {len(rows)} (seeds {', '.join(row['seed'] for row in rows)}) "
            f"| {thousands(steps) if steps is not None else '-'} | {f'{queries:g}' if queries is not None else '-'} "
            f"| {person_minutes(rows)} | {', '.join(sorted({row['device'] for row in rows}))} "
            f"| {', '.join(sorted({row['commit'] for row in rows}))} |"
        )
    return lines


def person_minutes(rows: list[dict[str, str]]) -> str:
    """The median of the rows' person minutes; "not recorded" where no row has them (rows written before)."""
    minutes = [float(row["person_minutes"]) for row in rows if row.get("person_minutes")]
    return f"{median(minutes):.1f}" if minutes else "not recorded"


def robot_rows(path: Path = ROBOT_CSV) -> dict[str, list[dict[str, str]]]:
    """robot.csv's rows by "preset, help" (a row from before the help column: none), by seed."""
    if not path.exists():
        return {}
    by_group: dict[str, list[dict[str, str]]] = {}
    with path.open() as file:
        rows = [{**row, "help": row.get("help") or "none"} for row in csv.DictReader(file)]
    for row in sorted(rows, key=lambda row: (row["preset"], row["help"] != "none", row["help"], int(row["seed"]))):
        by_group.setdefault(f"{row['preset']}, {row['help']}", []).append(row)
    return by_group


def robot_within(row: dict[str, str]) -> bool:
    """A stand-in seed reached its preset's target: ROBOT_RATE within the env steps, at most the queries."""
    steps, queries = ROBOT_TARGETS[row["preset"]]
    reached = row["steps_to_target"]
    return bool(reached) and int(reached) <= steps and int(row["queries"]) <= queries


def robot_target_text(preset: str) -> str:
    steps, queries = ROBOT_TARGETS[preset]
    return f"{ROBOT_RATE:.0%} within {thousands(steps)}, ≤ {queries} queries"


def robot_lines(by_group: dict[str, list[dict[str, str]]]) -> list[str]:
    lines = [
        "| preset | help | seed | steps to 90% | env steps run | queries | SAC updates per robot step | person minutes "
        "| take-over minutes | resets | robot's wait for them (min) | minutes | within the target | device | commit |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for rows in by_group.values():
        for row in rows:
            steps = steps_reached(row)
            wait = float(row["reset_wait_seconds"] or 0) / 60
            by_hand = float(row.get("takeover_seconds") or 0) / 60
            lines.append(
                f"| {row['preset']} | {row['help']} | {row['seed']} | {steps} | {int(row['env_steps']):,} "
                f"| {row['queries']} | {row['updates_per_step']} | {row['person_minutes']} | {by_hand:.1f} "
                f"| {row['resets']} | {wait:.1f} | {row['wall_minutes']} | {'yes' if robot_within(row) else 'no'} "
                f"| {row['device']} | {row['commit']} |"
            )
    if len(lines) == 2:
        lines.append("| - | - | - | - | - | - | - | - | - | - | - | - | - | - | - |")
    return lines


def plot_robot() -> None:
    """Each stand-in seed's eval success (by the env's ground truth) against env steps to its preset's budget: one
    panel per preset and kind of help, side by side."""
    panels: dict[tuple[str, str], dict[str, list[tuple[float, float]]]] = {}
    for path in sorted(ROBOT_FIGURES.glob("*.json")) if ROBOT_FIGURES.exists() else []:
        figures = json.loads(path.read_text())
        points = [(float(row["step"]), float(row["success_rate"])) for row in figures["evaluations"]]
        panels.setdefault((figures["preset"], figures.get("help", "none")), {})[f"seed {figures['seed']}"] = points
    if not panels:
        return
    images = []
    for (preset, helped), series in sorted(panels.items(), key=lambda item: (item[0][0], HELP_KINDS.index(item[0][1]))):
        drawn = io.BytesIO()
        title = f"pusher stand-in at 5 Hz, {preset}, help: {helped}"
        budget = float(ROBOT_TARGETS[preset][0])
        line_plot(drawn, dict(sorted(series.items())), title=title, y_range=(0.0, 1.0), x_max=budget, size=(600, 420))
        images.append(Image.open(drawn))
    figure = Image.new("RGB", (sum(image.width for image in images), images[0].height), "white")
    for index, image in enumerate(images):
        figure.paste(image, (index * images[0].width, 0))
    figure.save(ROBOT_PLOT)
    print(f"plot: {ROBOT_PLOT.relative_to(ROOT)}")


def steps_reached(row: dict[str, str]) -> str:
    """A row's env steps to its target, or that it did not reach it."""
    return f"{int(row['steps_to_target']):,}" if row["steps_to_target"] else "not reached"


def per_seed_lines(by_task: dict[str, list[dict[str, str]]]) -> list[str]:
    lines = [
        "| task | seed | steps to target | env steps run | queries (yes) | minutes | within the target | device "
        "| commit |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for task, rows in by_task.items():
        for row in rows:
            steps = steps_reached(row)
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
    rows, noisy, robot = seed_rows(SEEDS_CSV), seed_rows(NOISE_CSV), robot_rows()
    return {
        "summary": summary_lines(rows, robot), "seeds": per_seed_lines(rows), "noise": per_seed_lines(noisy),
        "robot": robot_lines(robot), **{f"compare-{task}": comparison(task)[0] for task in COMPARED_TASKS},
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


def plot_comparisons() -> None:
    """Each compared task's plot, docs/results/<task>-methods.png, where it has runs."""
    for task in COMPARED_TASKS:
        _, series, bands = comparison(task)
        if not series:
            continue
        plot = RESULTS / f"{task}-methods.png"
        title = f"{task}: eval success, mean and min-max over seeds 0-2, per reward method"
        line_plot(plot, series, title=title, y_range=(0.0, 1.0), bands=bands)
        print(f"plot: {plot.relative_to(ROOT)}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tables", action="store_true", help="only the tables, not the plot")
    parser.add_argument("--check", action="store_true", help="with --tables: only say whether they are stale")
    args = parser.parse_args()
    if not args.tables:
        plot_comparisons()
        plot_robot()
    return write_tables(check=args.check)


if __name__ == "__main__":
    sys.exit(main())
