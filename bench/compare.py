"""Several bench/learn.py runs side by side: one plot of their eval success rates and a Markdown table.

    python bench/compare.py bench/out/pusher-vice_raq-seed0 bench/out/pusher-vice_raq-seed1 --out docs/pusher.png

Reads each run's curve.csv and summary.json (as bench/learn.py writes them).
"""

import argparse
import csv
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.plot import line_plot  # noqa: E402


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


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", type=Path, help="bench/out/<run> directories")
    parser.add_argument("--out", type=Path, required=True, help="PNG to write")
    parser.add_argument("--title", default="eval success rate")
    args = parser.parse_args()
    series = {run_dir.name: success_curve(run_dir) for run_dir in args.runs}
    line_plot(args.out, series, title=args.title, y_range=(0.0, 1.0))
    print("| run | first ≥ 90% eval success | env steps run | last eval success | queries | wall | updates/s | ended |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for run_dir in args.runs:
        print(table_row(json.loads((run_dir / "summary.json").read_text())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
