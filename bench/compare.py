"""Several bench/learn.py runs side by side: one plot of their eval success rates and a Markdown table.

    python bench/compare.py bench/out/pusher-vice_raq-seed0 bench/out/pusher-vice_raq-seed1 --out docs/pusher.png

With `--by-method` the runs are grouped by reward method (the paper's comparison, Fig. 5): one curve per method,
the mean over its seeds with the spread (min to max) shaded, at each evaluation every seed reached, and a table
per method. Reads each run's curve.csv and summary.json (as bench/learn.py writes them); a run's method and seed
come from its name, `<task>-<algorithm>-seed<N>`.
"""

import argparse
import csv
import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from app.routers.compare import mean_and_spread  # noqa: E402
from bench.plot import line_plot  # noqa: E402
from contract.algorithms import ALGORITHM_SPECS, ALGORITHMS  # noqa: E402

RUN_NAME = re.compile(r"^(?P<task>[a-z]+)-(?P<algorithm>[a-z_]+)-seed(?P<seed>\d+)$")


def success_curve(run_dir: Path) -> list[tuple[float, float]]:
    """(env step, eval success rate) at each evaluation of the run."""
    with (run_dir / "curve.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    curve: dict[float, float] = {}
    for row in rows:
        step = float(row["step"])
        value = row.get("eval/success_rate")
        if value not in (None, "") and step % 1000 == 0:
            curve[step] = float(value)
    return sorted(curve.items())


def table_row(summary: dict[str, object]) -> str:
    reached = summary.get("steps_to_90pct_success")
    cells = [
        str(summary["run"]),
        f"{reached:,}" if isinstance(reached, int) else "not reached",
        f"{summary['env_steps']:,}",
        f"{summary['final_success_rate']:.0%}" if summary.get("final_success_rate") is not None else "-",
        f"{summary['queries_asked']} ({summary['queries_yes']} yes)",
        f"{summary['wall_minutes']} min",
        f"{summary['updates_per_second']}",
        str(summary.get("stopped_because") or summary["status"]),
    ]
    return "| " + " | ".join(cells) + " |"


def method_of(summary: dict[str, object]) -> str:
    """The reward method of a run, from its name (`pusher-vice_raq-seed0`)."""
    match = RUN_NAME.match(str(summary["run"]))
    if match is None or match["algorithm"] not in ALGORITHM_SPECS:
        raise SystemExit(f"cannot tell the method of run {summary['run']!r} (expected <task>-<algorithm>-seed<N>)")
    return match["algorithm"]


def first_at_least(curve: list[tuple[float, float]], rate: float) -> int | None:
    return next((int(step) for step, value in curve if value >= rate - 1e-9), None)


MethodRuns = dict[str, list[tuple[dict[str, object], list[tuple[float, float]]]]]
"""Per reward method, each run's summary.json and its eval success curve."""


def runs_by_method(run_dirs: list[Path], until: int | None = None) -> MethodRuns:
    """Each run's summary and curve, grouped by method; `until`: the last env step compared (the horizon)."""
    runs: MethodRuns = {}
    for run_dir in run_dirs:
        if not (run_dir / "summary.json").exists():  # a run that died before its first summary
            print(f"{run_dir}: no summary.json, left out", file=sys.stderr)
            continue
        summary = json.loads((run_dir / "summary.json").read_text())
        curve = [(step, value) for step, value in success_curve(run_dir) if until is None or step <= until]
        runs.setdefault(method_of(summary), []).append((summary, curve))
    return {name: runs[name] for name in ALGORITHMS if name in runs}  # the one list of methods, in its order


def method_table(runs: MethodRuns) -> tuple[list[str], dict[str, list], dict[str, list]]:
    """The Markdown table per method, and each method's mean curve and spread (min to max) to plot."""
    series, bands = {}, {}
    lines = [
        "| method | seeds | evaluations to | reached 90% | env steps to first 90% (each seed) "
        "| mean eval success over the run | last 5 evaluations | queries (yes), each seed |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for method, members in runs.items():
        curves = [curve for _, curve in members]
        points = mean_and_spread([{int(step): value for step, value in curve} for curve in curves])
        if not points:  # its seeds share no evaluation (one stopped before its first)
            lines.append(f"| {method} | {len(curves)} | no evaluation every seed reached | - | - | - | - | - |")
            continue
        label = f"{method} ({len(curves)} seed{'' if len(curves) == 1 else 's'})"
        series[label] = [(step, mean) for step, mean, *_ in points]
        bands[label] = [(step, low, high) for step, _, low, high, _ in points]
        means = [mean for _, mean, *_ in points]
        reached = [first_at_least([(s, v) for s, v in curve if s <= points[-1][0]], 0.9) for curve in curves]
        # (queries: each run's whole count, also where it ran past `until`)
        queries = ", ".join(f"{summary['queries_asked']} ({summary['queries_yes']})" for summary, _ in members)
        lines.append(
            f"| {method} | {len(curves)} | {points[-1][0]:,.0f} | {sum(r is not None for r in reached)} of "
            f"{len(curves)} | {', '.join(f'{r:,}' if r is not None else '-' for r in reached)} "
            f"| {sum(means) / len(means):.0%} | {sum(means[-5:]) / len(means[-5:]):.0%} | "
            f"{queries if ALGORITHM_SPECS[method].queries else '-'} |"
        )
    return lines, series, bands


def by_method(run_dirs: list[Path], out: Path, title: str, until: int | None = None) -> list[str]:
    """The mean-and-spread plot per method written to `out`, and its Markdown table (returned as lines)."""
    lines, series, bands = method_table(runs_by_method(run_dirs, until))
    line_plot(out, series, title=title, y_range=(0.0, 1.0), bands=bands)
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", type=Path, help="bench/out/<run> directories")
    parser.add_argument("--out", type=Path, required=True, help="PNG to write")
    parser.add_argument("--title", default="eval success rate")
    parser.add_argument("--by-method", action="store_true", help="one mean curve with its spread per method")
    parser.add_argument("--until", type=int, default=None, help="--by-method: the last env step compared")
    args = parser.parse_args()
    if args.by_method:
        print("\n".join(by_method(args.runs, args.out, args.title, args.until)))
        return 0
    series = {run_dir.name: success_curve(run_dir) for run_dir in args.runs}
    line_plot(args.out, series, title=args.title, y_range=(0.0, 1.0))
    print("| run | first ≥ 90% eval success | env steps run | last eval success | queries | wall | updates/s | ended |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for run_dir in args.runs:
        if (run_dir / "summary.json").exists():
            print(table_row(json.loads((run_dir / "summary.json").read_text())))
        else:  # a run whose script died before its summary: its curve is still plotted
            reached = first_at_least(series[run_dir.name], 0.9)
            print(f"| {run_dir.name} | {f'{reached:,}' if reached else 'not reached'} | no summary.json | |||||")
    return 0


if __name__ == "__main__":
    sys.exit(main())
