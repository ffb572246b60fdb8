"""bench/learn.py end to end, as a learning run uses it: a real store, `raq serve`, `raq oracle` and `raq learn` on
a simulated task with its preset, down to its curve and summary; and bench/seeds.py over two seeds."""

import csv
import io
import json
import subprocess
import sys
import time
from pathlib import Path

from PIL import Image

from app.migrate import upgrade
from contract.effort import EFFORT_COLUMNS
from contract.store import Store

ROOT = Path(__file__).resolve().parent.parent
SMALL = [  # a run of seconds: small networks and images, short intervals
    "image_size=16", "conv_filters=4", "hidden_dim=32", "batch_size=16", "classifier_batch_size=8", "episode_steps=25",
    "initial_random_steps=50", "epoch_steps=50", "eval_every=100", "eval_episodes=2", "checkpoint_every=100",
    "log_every=50", "display_size=32", "rollout_size=16", "replay_capacity=1000", "query_every=50",
]  # fmt: skip


def test_a_run_with_task_settings_writes_its_curve_and_summary(tmp_path: Path) -> None:
    out = tmp_path / "door-run"
    command = [
        sys.executable, "bench/learn.py", "--task", "door", "--task-settings", "--total-steps", "200", "--threads", "1",
        "--goals", "4", "--out", str(out), "--set", *SMALL,
    ]  # fmt: skip
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "finished" and summary["env_steps"] == 200
    assert summary["queries_asked"] == 4  # one every 50 steps (--set wins over the task's 1,000)
    assert "SUMMARY " + json.dumps(summary) in done.stdout
    with (out / "curve.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [int(row["step"]) for row in rows][-1] == 200
    assert (out / "curve.png").stat().st_size > 1000
    stored = subprocess.run(
        [sys.executable, "-c", "import sqlite3, sys; print(sqlite3.connect(sys.argv[1]).execute("
         "'select config from runs').fetchone()[0])", str(out / "data" / "raq.sqlite3")],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    config = json.loads(stored.stdout)
    assert config["query_every"] == 50 and config["query_budget"] == 50  # --set wins; the budget is the door's

    # --report writes them again from the run's database alone (a run whose script was killed before them)
    (out / "summary.json").unlink()
    (out / "curve.png").unlink()
    report = [sys.executable, "bench/learn.py", "--task", "door", "--report", "--out", str(out)]
    again = subprocess.run(report, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stdout[-2000:] + again.stderr[-2000:]
    rewritten = json.loads((out / "summary.json").read_text())
    assert {key: rewritten[key] for key in ("status", "env_steps", "queries_asked", "steps_to_90pct_success")} == {
        key: summary[key] for key in ("status", "env_steps", "queries_asked", "steps_to_90pct_success")
    }
    assert rewritten["stopped_because"] == "report" and rewritten["wall_minutes"] is not None
    assert (out / "curve.png").stat().st_size > 1000


def test_the_seeds_harness_runs_seeds_side_by_side_then_only_reports_them(tmp_path: Path) -> None:
    out, table = tmp_path / "seeds", tmp_path / "seeds.csv"
    command = [
        sys.executable, "bench/seeds.py", "--task", "pusher", "--seeds", "3-4", "--parallel", "2", "--budget", "150",
        "--goals", "4", "--out", str(out), "--csv", str(table), "--set", *SMALL,
    ]  # fmt: skip
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    assert "seed 3: started" in done.stdout and "seed 4: started" in done.stdout
    assert "| 3 | not reached (150) |" in done.stdout and "0 of 2 seeds within the target" in done.stdout
    assert (out / "pusher-vice_raq-seeds.png").stat().st_size > 1000
    with table.open() as handle:
        rows = list(csv.DictReader(handle))
    assert [(row["task"], row["seed"], row["steps_to_target"], row["env_steps"]) for row in rows] == [
        ("pusher", "3", "", "150"), ("pusher", "4", "", "150"),
    ]  # fmt: skip
    assert rows[0]["queries"] == "3" and rows[0]["device"] == "cpu" and rows[0]["target"] == "0.9"
    # what each seed cost the person, from its own store: the oracle answered through the API, with no page
    for row, seed in zip(rows, (3, 4), strict=True):
        store = Store(f"sqlite:///{out / f'pusher-vice_raq-seed{seed}' / 'data' / 'raq.sqlite3'}")
        answered = len(store.answer_times(run_id=store.list_runs()[0].id))
        store.dispose()
        assert {name: float(row[name]) for name in EFFORT_COLUMNS} == {
            "person_minutes": 0.0, "answers": answered, "answer_seconds": 0.0, "resets": 0, "reset_wait_seconds": 0.0,
            "takeovers": 0, "takeover_seconds": 0.0,
        }  # fmt: skip
        assert answered > 0

    # again: both are at their budget, so nothing runs, and their rows are replaced, not added
    again = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0 and "started" not in again.stdout
    with table.open() as handle:
        assert len(list(csv.DictReader(handle))) == 2


def test_the_seeds_tables_are_made_from_the_csv(tmp_path: Path) -> None:
    """A seed counts when it reached the target within the budget and the query budget; the last row of a seed
    wins; the README and docs/results.md hold what the repository's CSV gives."""
    sys.path.insert(0, str(ROOT))
    from bench.results import per_seed_lines, seed_rows, summary_lines
    from bench.seeds import CSV_COLUMNS

    rows = [
        ["pusher", "vice_raq", "0", "0.9", "", "20000", "4", "1", "20.0", "cpu", "aaa"],  # replaced below
        ["pusher", "vice_raq", "0", "0.9", "12000", "12000", "3", "2", "11.0", "cpu", "bbb"],
        ["pusher", "vice_raq", "1", "0.9", "16000", "16000", "30", "9", "15.0", "cpu", "bbb"],  # 30 > 25 queries
        ["pusher", "vice_raq", "2", "0.9", "8000", "8000", "2", "2", "8.0", "cpu", "bbb"],
        ["pusher", "vice", "3", "0.9", "8000", "8000", "0", "0", "8.0", "cpu", "bbb"],  # another method: left out
        ["door", "vice_raq", "0", "0.9", "", "100000", "50", "0", "130.0", "cpu", "bbb"],
    ]
    path = tmp_path / "seeds.csv"
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(CSV_COLUMNS)
        writer.writerows(rows)
    by_task = seed_rows(path)
    summary = summary_lines(by_task)
    pusher = "| pusher | 90% within 20K, median ≤ 12K, ≤ 25 queries | 2 of 3 (seeds 0, 1, 2) | 10K | 2.5 (2) |"
    assert f"{pusher} not recorded | cpu | bbb |" in summary
    assert "| door | 90% within 100K, ≤ 50 queries | 0 of 1 (seeds 0) | - | - | not recorded | cpu | bbb |" in summary
    assert "| picker | 80% within 100K, ≤ 50 queries | not measured | - | - | - | - | - |" in summary
    seeds = per_seed_lines(by_task)
    assert "| pusher | 1 | 16,000 | 16,000 | 30 (9) | 15.0 | no | cpu | bbb |" in seeds
    assert "| door | 0 | not reached | 100,000 | 50 (0) | 130.0 | no | cpu | bbb |" in seeds
    done = subprocess.run(
        [sys.executable, "bench/results.py", "--tables", "--check"], cwd=ROOT, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stdout + done.stderr


def _png() -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (16, 16), (90, 40, 0)).save(buffer, format="PNG")
    return buffer.getvalue()


def test_each_seeds_row_holds_what_its_run_cost_the_person_and_old_rows_still_read(tmp_path: Path) -> None:
    """A seed's effort columns come from its own store after the run (an answer seen on a page, a scene reset);
    rows written before the columns existed are kept with them empty and still make the tables."""
    sys.path.insert(0, str(ROOT))
    from bench.results import per_seed_lines, seed_rows, summary_lines
    from bench.seeds import CSV_COLUMNS, SeedResult, seed_effort, write_csv

    assert CSV_COLUMNS[-len(EFFORT_COLUMNS) :] == list(EFFORT_COLUMNS)
    folder = tmp_path / "pusher-vice_raq-seed1"
    (folder / "data").mkdir(parents=True)
    url = f"sqlite:///{folder / 'data' / 'raq.sqlite3'}"
    upgrade(url)
    store = Store(url)
    run_id = store.create_run(env_id="VisualPusher-v0", algorithm="vice_raq", config={}, total_steps=1000).id
    query = store.post_query(run_id=run_id, env_step=500, model_png=_png(), display_png=_png(), score=0.0)
    store.mark_query_shown(query_id=query.id)
    store.request_scene_reset(run_id=run_id)
    time.sleep(0.3)
    store.scene_ready(run_id=run_id)
    store.answer_query(query_id=query.id, success=True, labeler="me")
    store.dispose()
    effort = seed_effort(folder)
    assert (effort["answers"], effort["resets"]) == (1, 1)
    assert 0.2 <= float(effort["answer_seconds"]) < 5 and 0.2 <= float(effort["reset_wait_seconds"]) < 5
    assert float(effort["person_minutes"]) > 0
    assert seed_effort(tmp_path / "no-such-seed") == dict.fromkeys(EFFORT_COLUMNS, "")

    old_header = CSV_COLUMNS[: -len(EFFORT_COLUMNS)]
    path = tmp_path / "seeds.csv"
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(old_header)
        writer.writerow(["pusher", "vice_raq", "0", "0.9", "12000", "12000", "3", "2", "11.0", "cpu", "aaa"])
    result = SeedResult(
        task="pusher", algorithm="vice_raq", seed=1, target=0.9, steps_to_target=10_000, env_steps=10_000,
        queries=2, queries_yes=1, minutes=9.0, device="cpu", commit="bbb", effort=effort,
    )  # fmt: skip
    write_csv(path, [result])
    with path.open() as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0]) == CSV_COLUMNS
    assert [row["seed"] for row in rows] == ["0", "1"]
    assert all(rows[0][name] == "" for name in EFFORT_COLUMNS)  # the old row: kept, its effort unknown
    assert {name: rows[1][name] for name in EFFORT_COLUMNS} == {name: str(effort[name]) for name in EFFORT_COLUMNS}
    by_task = seed_rows(path)
    assert [row["seed"] for row in by_task["pusher"]] == ["0", "1"]
    assert "| pusher | 0 | 12,000 | 12,000 | 3 (2) | 11.0 | yes | cpu | aaa |" in per_seed_lines(by_task)
    assert any(line.startswith("| pusher |") and "2 of 2" in line for line in summary_lines(by_task))


def test_the_robot_table_is_made_from_robot_csv(tmp_path: Path) -> None:
    """bench/robot_standin.py's rows (one per seed and preset, a newer row replacing its seed's) make the robot
    table and the summary's stand-in row: a seed counts when it reached 90% within its preset's steps and queries,
    and the person's minutes are the median of the seeds'."""
    sys.path.insert(0, str(ROOT))
    from bench.results import robot_lines, robot_rows, summary_lines
    from bench.robot_standin import CSV_COLUMNS, write_rows

    def row(seed: int, steps: object, queries: int, minutes: float, commit: str = "ccc") -> dict[str, object]:
        values = dict.fromkeys(CSV_COLUMNS, "")
        values |= {
            "task": "pusher-standin", "seed": seed, "preset": "cpu_robot", "steps_to_target": steps,
            "env_steps": steps or 15_000, "queries": queries, "updates_per_step": 2.0, "wall_minutes": 40.0,
            "device": "cpu", "commit": commit, "person_minutes": minutes, "resets": 100, "reset_wait_seconds": 60.0,
        }  # fmt: skip
        return values

    path = tmp_path / "robot.csv"
    write_rows(path, [row(0, "", 50, 9.0, commit="old")])
    write_rows(path, [row(0, 12_000, 48, 3.0), row(1, 14_000, 51, 5.0), row(2, 16_000, 40, 7.0)])
    helped = {**row(0, 5_000, 20, 4.0), "help": "interventions", "takeover_seconds": 180.0}
    write_rows(path, [helped])  # (beside seed 0's row without help, not in its place)
    by_group = robot_rows(path)
    assert [r["seed"] for r in by_group["cpu_robot, none"]] == ["0", "1", "2"]  # seed 0's old row replaced
    assert [r["seed"] for r in by_group["cpu_robot, interventions"]] == ["0"]
    lines = robot_lines(by_group)
    assert (
        "| cpu_robot | none | 0 | 12,000 | 12,000 | 48 | 2.0 | 3.0 | 0.0 | 100 | 1.0 | 40.0 | yes | cpu | ccc |"
    ) in lines
    assert any(line.startswith("| cpu_robot | none | 1 | 14,000 |") and "| no |" in line for line in lines)
    assert any(line.startswith("| cpu_robot | none | 2 | 16,000 |") and "| no |" in line for line in lines)
    assert any(line.startswith("| cpu_robot | interventions | 0 | 5,000 |") and "| 4.0 | 3.0 |" in line
               for line in lines)  # fmt: skip
    summary = summary_lines({}, by_group)
    assert (
        "| pusher stand-in, 5 Hz, cpu_robot | 90% within 15K, ≤ 50 queries | 1 of 3 (seeds 0, 1, 2) | 12K | 48 "
        "| 5.0 | cpu | ccc |"
    ) in summary
    assert any(line.startswith("| pusher stand-in, 5 Hz, cpu_robot, a person's interventions |") for line in summary)
