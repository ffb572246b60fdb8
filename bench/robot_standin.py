"""The stand-in robot end to end: the simulated pusher behind the robot contract, paced at 5 Hz wall clock by the
real-time actor, trained with the real-robot preset, reset by an automated person through the REST API.

    python bench/robot_standin.py --seed 0                 # one seed to 6.2K env steps (about 21 minutes)
    python bench/robot_standin.py --seed 0 --steps 600     # a short look at the timing figures
    python bench/robot_standin.py --seed 0 --remote        # the actor as `raq actor` (remote_actor): the link
                                                           # through the database and the checkpoint store

It starts `raq serve`, `raq oracle` and one learner (`raq learn --once`) on a fresh SQLite database, with 80 goal
photos from `raq goals` at 84x84 and `TrainConfig.real_robot()` on `robot.standin:PusherStandIn-v0` (a person's
reset before every episode: a resetter thread here presses Ready through POST /api/runs/{id}/robot/ready, as
`raq oracle` answers the questions). Meanwhile it measures:

- the actor's control period (mean, p99 and max of each logging window's `actor/period_ms_*`);
- Stop robot: POST …/robot/stop at a few steps, the time until the actor reports "stopped", then Resume;
- the eval success by the env's ground truth, in a separate process: each policy the learner writes (policy.pt,
  every eval_every steps) runs EVAL_EPISODES episodes of the stand-in unpaced, deterministically;
- at the end, SIGKILL of the learner and the time until its actor reports the arm held safe.

It prints the figures and writes them to <out>/figures.json.
"""

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from app.demo import add_simulated_goal_set  # noqa: E402
from app.migrate import upgrade  # noqa: E402
from bench.learn import free_port, wait_for_health  # noqa: E402
from bench.processes import stop_all  # noqa: E402
from contract.config import REAL_ROBOT_GOAL_IMAGES, TrainConfig  # noqa: E402
from contract.store import Store  # noqa: E402

STANDIN = "robot.standin:PusherStandIn-v0"
EVAL_EPISODES = 10
"""Episodes per evaluation of a written policy (by the env's ground truth)."""
TARGET_RATE, TARGET_STEPS, TARGET_QUERIES = 0.9, 6_200, 25
"""The paper's real-robot pusher: 90% success within 6.2K env steps and 25 queries."""
KILL_BEFORE_END = 100
"""The learner is killed this many env steps before its last (a learner that lags its actor may finish soon after)."""
STOP_AT = (1_500, 3_000, 4_500)
"""Env steps at which Stop robot is pressed (and Resume 2 s later)."""


def request(url: str, method: str = "GET") -> dict:
    data = b"" if method == "POST" else None
    call = urllib.request.Request(url, method=method, data=data, headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(call, timeout=10) as response:
        return json.loads(response.read())


def resetter(url: str, done: threading.Event, presses: list[float]) -> None:
    """The automated person: presses Ready through the API whenever an actor waits for a reset."""
    while not done.is_set():
        try:
            for robot in request(f"{url}/api/robots"):
                if robot["reset_needed"]:
                    request(f"{url}/api/runs/{robot['run_id']}/robot/ready", "POST")
                    presses.append(time.monotonic())
        except OSError:
            pass
        done.wait(0.1)


def wait_for_state(url: str, run_id: int, state: str, timeout: float) -> float | None:
    """Seconds until the run's actor reports `state` (polled every 5 ms), or None after `timeout`."""
    started = time.monotonic()
    while time.monotonic() - started < timeout:
        if request(f"{url}/api/runs/{run_id}/robot")["actor_state"] == state:
            return time.monotonic() - started
        time.sleep(0.005)
    return None


# ---------------------------------------------------------------------- the separate evaluation process
def evaluate_policies(policy_file: Path, out: Path, done_file: Path) -> None:
    """Evaluate each new policy.pt by the stand-in's ground truth until `done_file` appears."""
    import torch  # noqa: PLC0415

    from contract.envs import make_env  # noqa: PLC0415
    from learner.policy import load_policy  # noqa: PLC0415

    torch.set_num_threads(1)
    os.nice(10)  # (the actor's period is what is measured)
    env = make_env(STANDIN, image_size=84, display_size=64)
    seen = -1
    while not done_file.exists():
        if not policy_file.exists():
            time.sleep(1.0)
            continue
        try:
            policy = load_policy(policy_file)
        except Exception:  # (caught mid-write: the next look reads it whole)
            time.sleep(1.0)
            continue
        if policy.step == seen:
            time.sleep(1.0)
            continue
        seen, successes = policy.step, []
        for episode in range(EVAL_EPISODES):
            obs, info = env.reset(seed=1_000_000 + episode)
            for _ in range(100):
                obs, _, _, truncated, info = env.step(policy.env_action(obs, env))
                if truncated:
                    break
            successes.append(float(env.unwrapped.ground_truth()["success"]))
        rate = float(np.mean(successes))
        with out.open("a") as file:
            file.write(json.dumps({"step": policy.step, "success_rate": rate}) + "\n")
        print(f"evaluation of the policy at step {policy.step}: success {rate:.2f}", flush=True)


# ---------------------------------------------------------------------- the bench
def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", type=int, default=TARGET_STEPS, help="env steps to train for")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--remote", action="store_true", help="the actor as its own `raq actor` (remote_actor)")
    parser.add_argument("--evaluate", nargs=3, metavar=("POLICY", "OUT", "DONE"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.evaluate:
        evaluate_policies(*(Path(value) for value in args.evaluate))
        return 0
    out = args.out or ROOT / "bench" / "out" / f"robot-standin-seed{args.seed}"
    data_dir = out / "data"
    if data_dir.exists():
        raise SystemExit(f"{data_dir} exists: remove it or choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    database_url = f"sqlite:///{(data_dir / 'raq.sqlite3').resolve()}"
    data_dir.mkdir()
    upgrade(database_url)
    store = Store(database_url)
    goal_set_id = add_simulated_goal_set(
        store, task="pusher", name="stand-in goals", count=REAL_ROBOT_GOAL_IMAGES, image_size=84
    )
    config = TrainConfig.real_robot(
        env_id=STANDIN, seed=args.seed, total_steps=args.steps, eval_every=500, remote_actor=args.remote
    )
    run = store.create_run(
        name=f"stand-in seed {args.seed}", env_id=STANDIN, algorithm=config.algorithm, config=config.to_dict(),
        seed=args.seed, goal_set_id=goal_set_id, total_steps=args.steps,
    )  # fmt: skip
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    env = {**os.environ, "RAQ_DATA_DIR": str(data_dir), "RAQ_PORT": str(port), "PYTHONUNBUFFERED": "1"}
    env.setdefault("MUJOCO_GL", "egl")
    for name in ("RAQ_DATABASE_URL", "DATABASE_URL"):
        env.pop(name, None)
    raq = [sys.executable, "-m", "cli"]
    logs = {key: (out / f"{key}.log").open("w") for key in ("serve", "oracle", "learn", "evaluate", "actor")}
    evaluations, done_file = out / "evaluations.jsonl", out / "evaluation-done"
    evaluations.unlink(missing_ok=True)
    done_file.unlink(missing_ok=True)
    policy_file = data_dir / "checkpoints" / f"run-{run.id}" / "policy.pt"
    processes = [subprocess.Popen(raq + ["serve", "--port", str(port)], env=env, stdout=logs["serve"],
                                  stderr=subprocess.STDOUT)]  # fmt: skip
    done, presses = threading.Event(), []
    figures: dict[str, object] = {"seed": args.seed, "steps": args.steps, "env_id": STANDIN, "remote": args.remote}
    started = time.monotonic()
    try:
        wait_for_health(url)
        oracle = raq + ["oracle", "--url", url, "--run", str(run.id), "--seed", str(args.seed)]
        processes.append(subprocess.Popen(oracle, env=env, stdout=logs["oracle"], stderr=subprocess.STDOUT))
        evaluate = [sys.executable, __file__, "--evaluate", str(policy_file), str(evaluations), str(done_file)]
        processes.append(subprocess.Popen(evaluate, env=env, stdout=logs["evaluate"], stderr=subprocess.STDOUT))
        if args.remote:  # on the robot's host, sharing only the database and the checkpoint store
            actor = raq + ["actor", "--run", str(run.id)]
            processes.append(subprocess.Popen(actor, env=env, stdout=logs["actor"], stderr=subprocess.STDOUT))
        learner = subprocess.Popen(raq + ["learn", "--once"], env=env, stdout=logs["learn"], stderr=subprocess.STDOUT)
        processes.append(learner)
        threading.Thread(target=resetter, args=(url, done, presses), daemon=True).start()
        stops: list[float | None] = []
        for stop_step in (step for step in STOP_AT if step < args.steps):
            while store.get_run(run_id=run.id).step < stop_step and learner.poll() is None:
                time.sleep(0.5)
            request(f"{url}/api/runs/{run.id}/robot/stop", "POST")
            stops.append(wait_for_state(url, run.id, "stopped", timeout=10))
            time.sleep(2.0)
            request(f"{url}/api/runs/{run.id}/robot/resume", "POST")
            print(f"step {stop_step}: stop honoured in {stops[-1]} s; resumed", flush=True)
        while store.get_run(run_id=run.id).step < args.steps - KILL_BEFORE_END and learner.poll() is None:
            time.sleep(1.0)
        learner.send_signal(signal.SIGKILL)
        held = wait_for_state(url, run.id, "held safe: learner gone", timeout=10)
        figures["stop_seconds"] = stops
        figures["held_after_sigkill_seconds"] = held
    finally:
        done.set()
        done_file.touch()
        stop_all(processes, signal.SIGINT, timeout=60)
        for log in logs.values():
            log.close()
    figures["wall_minutes"] = (time.monotonic() - started) / 60
    names = ["actor/period_ms_mean", "actor/period_ms_p99", "actor/period_ms_max", "queries/asked"]
    metrics = {name: [(m.step, m.value) for m in store.metrics(run_id=run.id, names=[name])] for name in names}
    p99 = [value for _, value in metrics["actor/period_ms_p99"]]
    figures["period_ms_mean"] = float(np.mean([value for _, value in metrics["actor/period_ms_mean"]]))
    figures["period_ms_p99_median_window"] = float(np.median(p99))
    figures["period_ms_p99_worst_window"] = float(max(p99))
    figures["period_ms_max"] = float(max(value for _, value in metrics["actor/period_ms_max"]))
    rows = [json.loads(line) for line in evaluations.read_text().splitlines()] if evaluations.exists() else []
    figures["evaluations"] = rows
    reached = next((row["step"] for row in rows if row["success_rate"] >= TARGET_RATE), None)
    figures["steps_to_target"] = reached
    asked = [(step, value) for step, value in metrics["queries/asked"] if reached is None or step <= reached]
    figures["queries"] = int(asked[-1][1]) if asked else 0
    figures["best_success_rate"] = max((row["success_rate"] for row in rows), default=None)
    figures["resets"] = len(presses)
    (out / "figures.json").write_text(json.dumps(figures, indent=2) + "\n")
    print(json.dumps(figures, indent=2))
    store.dispose()
    return 0


if __name__ == "__main__":
    sys.exit(main())
