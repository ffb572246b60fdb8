"""A live learner keeps its claim on a busy machine: the gaps between its heartbeats while other processes load
the cores.

    python bench/heartbeat_gaps.py --load 8 --seconds 240

One learner (`raq learn --once`) trains a pusher run (VICE-RAQ, its classifier epochs and checkpoints included) on
a fresh SQLite store while `--load` processes spin on the cores at the learner's priority. The run's heartbeat_at is
read every POLL_SECONDS; each change is a heartbeat. It prints the longest gap between two heartbeats against twice
`heartbeat_seconds` (a learner is taken over once it has been silent RAQ_STALE_HEARTBEAT_SECONDS, 60 by default),
the number of heartbeats and the load average, and writes <out>/figures.json.
"""

import argparse
import json
import multiprocessing
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from app.demo import add_simulated_goal_set  # noqa: E402
from app.migrate import upgrade  # noqa: E402
from bench.processes import stop_all  # noqa: E402
from contract.config import TrainConfig  # noqa: E402
from contract.store import RunStatus, Store  # noqa: E402

POLL_SECONDS = 0.25


def spin(until: float) -> None:
    """Keep a core busy until the monotonic time `until`."""
    while time.monotonic() < until:
        pass


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--load", type=int, default=8, help="busy processes beside the learner")
    parser.add_argument("--seconds", type=float, default=240.0, help="how long the load lasts")
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "out" / "heartbeat-gaps")
    args = parser.parse_args()
    if args.out.exists():
        raise SystemExit(f"{args.out} exists: remove it or choose another --out")
    data = args.out / "data"
    data.mkdir(parents=True)
    url = f"sqlite:///{(data / 'raq.sqlite3').resolve()}"
    upgrade(url)
    store = Store(url)
    config = TrainConfig(env_id="VisualPusher-v0", total_steps=100_000, checkpoint_every=2_000)
    run_id = store.create_run(
        name="heartbeats", env_id=config.env_id, algorithm=config.algorithm, config=config.to_dict(),
        goal_set_id=add_simulated_goal_set(store, task="pusher", name="goals", count=10),
        total_steps=config.total_steps,
    ).id  # fmt: skip
    env = {**{k: v for k, v in os.environ.items() if not k.startswith("RAQ_")}, "RAQ_DATABASE_URL": url,
           "RAQ_DATA_DIR": str(data), "PYTHONPATH": str(ROOT)}  # fmt: skip
    env.setdefault("MUJOCO_GL", "egl")
    log = (args.out / "learn.log").open("w")
    learner = subprocess.Popen([sys.executable, "-m", "cli", "learn", "--once"], env=env, stdout=log,
                               stderr=subprocess.STDOUT, cwd=ROOT)  # fmt: skip
    beats: list[float] = []
    loads: list[float] = []
    spinners: list[multiprocessing.Process] = []
    try:
        while store.get_run(run_id=run_id).status != RunStatus.TRAINING:
            time.sleep(POLL_SECONDS)
        until = time.monotonic() + args.seconds
        spinners = [multiprocessing.Process(target=spin, args=(until,)) for _ in range(args.load)]
        for spinner in spinners:
            spinner.start()
        last = None
        while time.monotonic() < until and learner.poll() is None:
            beat = store.get_run(run_id=run_id).heartbeat_at
            if beat != last:
                beats.append(beat.timestamp())
                last = beat
            loads.append(os.getloadavg()[0])
            time.sleep(POLL_SECONDS)
    finally:
        for spinner in spinners:
            spinner.join(timeout=args.seconds + 10)
        store.request_stop(run_id=run_id)
        stop_all([learner], timeout=120)
        log.close()
    gaps = [later - earlier for earlier, later in zip(beats, beats[1:], strict=False)]
    figures = {
        "load_processes": args.load, "seconds": args.seconds, "heartbeat_seconds": config.heartbeat_seconds,
        "heartbeats": len(beats), "longest_gap_seconds": round(max(gaps), 2) if gaps else None,
        "load_average_median": round(sorted(loads)[len(loads) // 2], 1) if loads else None,
        "steps": store.get_run(run_id=run_id).step,
    }  # fmt: skip
    (args.out / "figures.json").write_text(json.dumps(figures, indent=2) + "\n")
    print(
        f"longest heartbeat gap: {figures['longest_gap_seconds']} s (limit {2 * config.heartbeat_seconds:g} s) over "
        f"{len(beats)} heartbeats in {args.seconds:g} s at load {figures['load_average_median']}"
    )
    store.dispose()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
