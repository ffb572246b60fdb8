"""The stand-in robot end to end: the simulated pusher behind the robot contract, paced at 5 Hz wall clock by the
real-time actor, trained with a robot preset, reset by an automated person through the REST API.

    python bench/robot_standin.py --seeds 0-2 --parallel 3 --threads 1    # the CPU preset's seeds, robot.csv rows
    python bench/robot_standin.py --seeds 0 --steps 600                   # a short look at the timing figures
    python bench/robot_standin.py --seeds 0 --set device=cuda             # the paper's preset on a GPU
    python bench/robot_standin.py --seeds 1 --steps 1600 --actor remote --probes   # `raq actor` (remote_actor), probed
    python bench/robot_standin.py --seeds 0-5 --parallel 3 --threads 1 --with-help interventions   # a person's hands

Each seed starts `raq serve`, `raq oracle` and one learner (`raq learn --once`) on a fresh SQLite database, with
80 goal photos from the stand-in's own camera (`robot.standin.goal_photos`, kept as the Camera panel keeps them)
and the robot preset for the learner's device (`contract.config.robot_preset_for`: `TrainConfig.cpu_robot()` on
a CPU, `real_robot()` on a GPU; `--preset` picks another, `--set FIELD=VALUE` changes single fields) on
`robot.standin:PusherStandIn-v0`. A person's reset
comes before every episode: a resetter thread presses Ready through POST /api/runs/{id}/robot/ready, as
`raq oracle` answers the questions. Meanwhile it measures:

- the actor's control period (mean, p99 and max of each logging window's `actor/period_ms_*`);
- SAC updates per robot step (`perf/updates_per_robot_step`, the mean of its windows);
- the eval success by the env's ground truth, in a separate process: each policy the learner writes (policy.pt,
  every eval_every steps) runs EVAL_EPISODES episodes of the stand-in unpaced, deterministically; the run stops at
  the first at TARGET_RATE (unless --keep-going);
- what the run cost the person (contract.effort, from the seed's own store);
- with --probes: Stop robot at STOP_AT steps (Resume 2 s later) and, at the end, SIGKILL of the learner and the
  time until its actor reports the arm held safe.

`--with-help interventions`: an automated person also takes the arm over by hand, as the run page lets a person do
(bench/helping_person.py: the scripted pusher expert, often in the early episodes and less and less after, through
POST /api/runs/ID/robot/drive); the stand-in then tells it where the mug and hand are (bench/seen_standin.py).
`--with-help demos`: the same person records DEMO_EPISODES demos first (Record demos, each driven from its first
step and ended with the success key) and never takes over after. The row's `help` column says which.

Each seed writes <out>/seed<N>/figures.json; every seed's row goes to --csv (docs/results/robot.csv), replacing
an earlier row of the same seed and preset, and its figures (its evaluations: the curve of bench/results.py's plot)
to robot/<preset>-seed<N>.json beside it. `--report` only does that for the seeds already run in --out.
"""

import argparse
import csv
import io
import json
import math
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

from app.migrate import upgrade  # noqa: E402
from bench.learn import free_port, parse_overrides, wait_for_health  # noqa: E402
from bench.processes import stop_all  # noqa: E402
from bench.seeds import current_commit, parse_seeds  # noqa: E402
from contract.config import REAL_ROBOT_GOAL_IMAGES, ROBOT_PRESETS, TrainConfig, robot_preset_for  # noqa: E402
from contract.effort import EFFORT_COLUMNS, run_effort  # noqa: E402
from contract.images import prepare_upload  # noqa: E402
from contract.learner_pace import PACE_METRIC  # noqa: E402
from contract.store import Store  # noqa: E402

HELP_KINDS = ("none", "interventions", "demos")
DEMO_EPISODES = 5
"""Episodes the automated person drives by hand before the policy acts (`--with-help demos`)."""
"""What a person's hands do for a seed: nothing, or take over now and then (bench/helping_person.py)."""

STANDIN = "robot.standin:PusherStandIn-v0"
TASK = "pusher-standin"
"""The task's name in robot.csv."""
EVAL_EPISODES = 10
"""Episodes per evaluation of a written policy (by the env's ground truth)."""
TARGET_RATE = 0.9
LAST_EVALUATION_SECONDS = 180.0
"""How long a finished seed waits for the evaluation of its last policy."""
"""Success by the env's ground truth that counts as learned."""
TARGETS: dict[str, tuple[int, int]] = {"cpu_robot": (15_000, 50), "real_robot": (6_200, 25)}
"""Each preset's target: (env steps, queries) by which TARGET_RATE is to be reached. The CPU preset's is the
lockstep pusher's budget at 5 Hz (50 minutes); the paper's real-robot pusher reached it within 6.2K steps and 25
queries."""
KILL_BEFORE_END = 100
"""With --probes, the learner is killed this many env steps before its last."""
STOP_AT = (1_500, 3_000, 4_500)
"""With --probes, env steps at which Stop robot is pressed (and Resume 2 s later)."""
ROBOT_CSV = ROOT / "docs" / "results" / "robot.csv"
CSV_COLUMNS = [
    "task", "seed", "preset", "help", "steps_to_target", "env_steps", "queries", "updates_per_step", "period_ms_mean",
    "wall_minutes", "device", "commit", *EFFORT_COLUMNS,
]  # fmt: skip
"""robot.csv's columns: one row per seed, preset and help."""
ROW_KEY = ("task", "seed", "preset", "help")


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


def read_evaluations(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def wait_for_last_evaluation(store: Store, run_id: int, evaluations: Path, evaluator: subprocess.Popen) -> None:
    """Until the policy the run ended with has been evaluated (at most LAST_EVALUATION_SECONDS): a run that ends at
    its last step is judged on that step's policy too."""
    deadline = time.monotonic() + LAST_EVALUATION_SECONDS
    last = store.get_run(run_id=run_id).step
    while time.monotonic() < deadline and evaluator.poll() is None:
        if any(row["step"] >= last for row in read_evaluations(evaluations)):
            return
        time.sleep(1.0)


# ---------------------------------------------------------------------- the separate evaluation process
def evaluate_policies(policy_file: Path, out: Path, done_file: Path, image_size: int) -> None:
    """Evaluate each new policy.pt by the stand-in's ground truth until `done_file` appears."""
    import torch  # noqa: PLC0415

    from contract.envs import make_env  # noqa: PLC0415
    from learner.policy import load_policy  # noqa: PLC0415

    torch.set_num_threads(1)
    os.nice(10)  # (the actor's period is what is measured)
    env = make_env(STANDIN, image_size=image_size, display_size=64)
    env.unwrapped.arm(seconds=math.inf)  # (a simulation of its own for judging policies, not the robot: always armed)
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


# ---------------------------------------------------------------------- one seed
def standin_id(args: argparse.Namespace) -> str:
    """The stand-in's env id: one that shows the automated person the scene when it helps."""
    from bench.seen_standin import ENV_ID  # noqa: PLC0415

    return STANDIN if args.with_help == "none" else ENV_ID


def seed_config(args: argparse.Namespace, seed: int) -> tuple[str, TrainConfig]:
    """The preset's name and the seed's config: the preset, then --set's fields."""
    overrides = parse_overrides(args.set)
    preset = args.preset or robot_preset_for(str(overrides.get("device", "cpu"))).name
    config = getattr(TrainConfig, preset)(
        env_id=standin_id(args), seed=seed, total_steps=args.steps or TARGETS[preset][0], eval_every=500,
        remote_actor=args.actor == "remote", **overrides,
    )  # fmt: skip
    return preset, config


def add_camera_goal_set(store: Store, *, count: int, image_size: int, env_id: str = STANDIN) -> int:
    """A goal set of `count` photos from the stand-in's own camera (robot.standin.goal_photos), made as the
    Camera panel's capture makes them (the model's copy centre-cropped and resized as every observation is)."""
    from PIL import Image  # noqa: PLC0415

    from robot.standin import goal_photos  # noqa: PLC0415

    goal_set = store.create_goal_set(name="stand-in goals", image_size=image_size, env_id=env_id)
    for index, frame in enumerate(goal_photos(count)):
        buffer = io.BytesIO()
        Image.fromarray(frame).save(buffer, format="PNG")
        image = prepare_upload(
            buffer.getvalue(), filename=f"camera-{index:02d}.png", model_size=image_size,
            max_bytes=len(buffer.getvalue()), max_pixels=frame.shape[0] * frame.shape[1],
        )  # fmt: skip
        store.add_goal_example(
            goal_set_id=goal_set.id, filename=image.filename, original=image.original,
            original_media_type=image.media_type, width=image.width, height=image.height, model_png=image.model_png,
            display_png=image.display_png, source="camera",
        )  # fmt: skip
    return goal_set.id


def wait_for_robot(store: Store, process: subprocess.Popen, env_id: str) -> None:
    """Until the stand-in's own process has its row in the store (a learner then links to it)."""
    deadline = time.monotonic() + 120
    while store.robot_process_of(env_id=env_id) is None:
        if process.poll() is not None or time.monotonic() > deadline:
            raise SystemExit("the robot's process did not come up")
        time.sleep(0.2)


def run_seed(args: argparse.Namespace, seed: int, out: Path) -> dict:
    """One seed's run end to end; its figures."""
    data_dir = out / "data"
    if data_dir.exists():
        raise SystemExit(f"{data_dir} exists: remove it or choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    preset, config = seed_config(args, seed)
    target_steps, target_queries = TARGETS[preset]
    database_url = f"sqlite:///{(data_dir / 'raq.sqlite3').resolve()}"
    data_dir.mkdir()
    upgrade(database_url)
    store = Store(database_url)
    goal_set_id = add_camera_goal_set(
        store, count=REAL_ROBOT_GOAL_IMAGES, image_size=config.image_size, env_id=config.env_id
    )
    run = store.create_run(
        name=f"stand-in seed {seed}", env_id=config.env_id, algorithm=config.algorithm, config=config.to_dict(),
        seed=seed, goal_set_id=goal_set_id, total_steps=config.total_steps,
    )  # fmt: skip
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    env = {**os.environ, "RAQ_DATA_DIR": str(data_dir), "RAQ_PORT": str(port), "PYTHONUNBUFFERED": "1"}
    env.setdefault("MUJOCO_GL", "egl")
    seen = out / "seen.json"
    if args.with_help != "none":
        from bench.seen_standin import SEEN_VARIABLE  # noqa: PLC0415

        seen.unlink(missing_ok=True)
        env.update({SEEN_VARIABLE: str(seen), "RAQ_ENV_MODULES": "bench.seen_standin", "PYTHONPATH": str(ROOT)})
    if args.threads:
        env["OMP_NUM_THREADS"] = str(args.threads)
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
    evaluator: subprocess.Popen | None = None
    person = None  # (the automated person's hands, when it helps)
    figures: dict[str, object] = {
        "task": TASK, "seed": seed, "preset": preset, "help": args.with_help, "steps": config.total_steps,
        "env_id": config.env_id,
        "actor": args.actor, "device": config.device, "image_size": config.image_size,
        "conv_filters": config.conv_filters, "target_steps": target_steps, "target_queries": target_queries,
    }  # fmt: skip
    started = time.monotonic()
    try:
        wait_for_health(url)
        oracle = raq + ["oracle", "--url", url, "--run", str(run.id), "--seed", str(seed)]
        processes.append(subprocess.Popen(oracle, env=env, stdout=logs["oracle"], stderr=subprocess.STDOUT))
        evaluate = [sys.executable, __file__, "--evaluate", str(policy_file), str(evaluations), str(done_file),
                    str(config.image_size)]  # fmt: skip
        evaluator = subprocess.Popen(evaluate, env=env, stdout=logs["evaluate"], stderr=subprocess.STDOUT)
        processes.append(evaluator)
        # the robot's own process, sharing only the database and the checkpoint store with the learner
        actor = raq + (["actor", "--run", str(run.id)] if args.actor == "remote" else ["robot", config.env_id])
        processes.append(subprocess.Popen(actor, env=env, stdout=logs["actor"], stderr=subprocess.STDOUT))
        wait_for_robot(store, processes[-1], config.env_id)
        learner = subprocess.Popen(raq + ["learn", "--once"], env=env, stdout=logs["learn"], stderr=subprocess.STDOUT)
        processes.append(learner)
        threading.Thread(target=resetter, args=(url, done, presses), daemon=True).start()
        if args.with_help != "none":
            from bench.helping_person import HelpingPerson  # noqa: PLC0415

            demos = DEMO_EPISODES if args.with_help == "demos" else 0
            person = HelpingPerson(url, run.id, seen, seed=seed, control_hz=config.control_hz or 5.0, demos=demos)
            threading.Thread(target=person.run, args=(done,), daemon=True).start()
        if args.probes:
            probe(args, store, url, run.id, learner, figures)
        else:
            while learner.poll() is None:
                reached = any(row["success_rate"] >= TARGET_RATE for row in read_evaluations(evaluations))
                if reached and not args.keep_going:
                    print(f"eval success reached {TARGET_RATE}: stopping the run", flush=True)
                    store.request_stop(run_id=run.id)
                    learner.wait(timeout=300)
                    break
                time.sleep(1.0)
    finally:
        done.set()
        if evaluator is not None:
            wait_for_last_evaluation(store, run.id, evaluations, evaluator)
        done_file.touch()
        stop_all(processes, signal.SIGINT, timeout=60)
        for log in logs.values():
            log.close()
    figures["wall_minutes"] = round((time.monotonic() - started) / 60, 1)
    figures |= run_figures(store, run.id, read_evaluations(evaluations), warm_up=config.initial_random_steps)
    figures["resets"] = len(presses)
    if person is not None:
        figures["episodes_helped"], figures["actions_by_hand"] = person.episodes_helped, person.actions_sent
    figures["effort"] = run_effort(store, run.id).columns()
    figures["commit"] = current_commit()
    (out / "figures.json").write_text(json.dumps(figures, indent=2) + "\n")
    print(json.dumps(figures, indent=2))
    store.dispose()
    return figures


def probe(
    args: argparse.Namespace, store: Store, url: str, run_id: int, learner: subprocess.Popen, figures: dict
) -> None:
    """Stop robot at STOP_AT (Resume 2 s later) and, near the end, SIGKILL of the learner: how soon each holds."""
    stops: list[float | None] = []
    steps = int(figures["steps"])
    for stop_step in (step for step in STOP_AT if step < steps):
        while store.get_run(run_id=run_id).step < stop_step and learner.poll() is None:
            time.sleep(0.5)
        request(f"{url}/api/runs/{run_id}/robot/stop", "POST")
        stops.append(wait_for_state(url, run_id, "stopped", timeout=10))
        time.sleep(2.0)
        request(f"{url}/api/runs/{run_id}/robot/resume", "POST")
        print(f"step {stop_step}: stop honoured in {stops[-1]} s; resumed", flush=True)
    while store.get_run(run_id=run_id).step < steps - KILL_BEFORE_END and learner.poll() is None:
        time.sleep(1.0)
    learner.send_signal(signal.SIGKILL)
    figures["stop_seconds"] = stops
    figures["held_after_sigkill_seconds"] = wait_for_state(url, run_id, "held safe: learner gone", timeout=10)


def run_figures(store: Store, run_id: int, evaluations: list[dict], *, warm_up: int) -> dict:
    """The timing, pace and learning figures of a finished run, from its metrics and its evaluations; the pace
    over the windows after the warm-up's `warm_up` steps (no update is due before)."""
    names = [
        "actor/period_ms_mean", "actor/period_ms_p99", "actor/period_ms_max", "queries/asked", PACE_METRIC,
        "person/step_share",
    ]  # fmt: skip
    metrics = {name: [(m.step, m.value) for m in store.metrics(run_id=run_id, names=[name])] for name in names}
    figures: dict[str, object] = {"env_steps": int(store.get_run(run_id=run_id).step or 0)}
    p99 = [value for _, value in metrics["actor/period_ms_p99"]]
    if p99:
        figures["period_ms_mean"] = round(float(np.mean([v for _, v in metrics["actor/period_ms_mean"]])), 1)
        figures["period_ms_p99_median_window"] = round(float(np.median(p99)), 1)
        figures["period_ms_p99_worst_window"] = round(float(max(p99)), 1)
        figures["period_ms_max"] = round(float(max(v for _, v in metrics["actor/period_ms_max"])), 1)
    pace = [value for step, value in metrics[PACE_METRIC] if step > warm_up]
    figures["updates_per_step"] = round(float(np.mean(pace)), 2) if pace else None
    figures["evaluations"] = evaluations
    reached = next((row["step"] for row in evaluations if row["success_rate"] >= TARGET_RATE), None)
    figures["steps_to_target"] = reached
    asked = [(step, value) for step, value in metrics["queries/asked"] if reached is None or step <= reached]
    figures["queries"] = int(asked[-1][1]) if asked else 0
    figures["best_success_rate"] = max((row["success_rate"] for row in evaluations), default=None)
    figures["person_step_share"] = metrics["person/step_share"]  # (step, share of the steps since the last record)
    return figures


# ---------------------------------------------------------------------- the table
def write_rows(path: Path, rows: list[dict]) -> None:
    """Each seed's row into the CSV, replacing an earlier row of the same task, seed, preset and help (a row from
    before the help column: none)."""
    kept = []
    if path.exists():
        with path.open() as file:
            kept = [{**row, "help": row.get("help") or "none"} for row in csv.DictReader(file)]
    rows = [{**row, "help": row.get("help") or "none"} for row in rows]
    fresh = {tuple(str(row[k]) for k in ROW_KEY) for row in rows}
    kept = [row for row in kept if tuple(row[k] for k in ROW_KEY) not in fresh]
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=CSV_COLUMNS)
        writer.writeheader()
        for row in sorted(kept + rows, key=lambda row: (row["task"], row["preset"], row["help"], int(row["seed"]))):
            writer.writerow({name: row.get(name, "") for name in CSV_COLUMNS})


def keep_figures(csv_path: Path, figures_file: Path) -> dict:
    """A finished seed's figures: its row into the CSV, the figures beside it (robot/<preset>-seed<N>.json)."""
    figures = json.loads(figures_file.read_text())
    helped = "" if figures.get("help", "none") == "none" else f"-{figures['help']}"
    kept = csv_path.parent / "robot" / f"{figures['preset']}{helped}-seed{figures['seed']}.json"
    kept.parent.mkdir(parents=True, exist_ok=True)
    kept.write_text(json.dumps(figures, indent=2) + "\n")
    row = csv_row(figures)
    write_rows(csv_path, [row])
    return row


def csv_row(figures: dict) -> dict:
    row = {name: figures.get(name) for name in CSV_COLUMNS}
    row |= figures["effort"] | {"help": figures.get("help", "none")}
    return {name: "" if value is None else value for name, value in row.items()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", default="0", help='"0-2" or "0,2"')
    parser.add_argument("--parallel", type=int, default=1, help="seeds run side by side")
    parser.add_argument("--threads", type=int, default=None, help="torch threads of each learner (OMP_NUM_THREADS)")
    parser.add_argument("--preset", choices=sorted(ROBOT_PRESETS), default=None,
                        help="default: the one for --set device=... (cpu_robot on a CPU)")  # fmt: skip
    parser.add_argument("--set", nargs="*", default=[], metavar="FIELD=VALUE", help="other TrainConfig fields")
    parser.add_argument("--steps", type=int, default=None, help="env steps to train for (default: the target's)")
    parser.add_argument("--keep-going", action="store_true", help="train on past the target")
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "out" / "robot-standin")
    parser.add_argument("--csv", type=Path, default=ROBOT_CSV, help="the table every seed's row goes to")
    parser.add_argument("--report", action="store_true", help="only write the rows of the seeds run in --out")
    parser.add_argument(
        "--actor", choices=("robot", "remote"), default="robot",
        help="who drives the stand-in: its own process, `raq robot` (default), or `raq actor --run ID` for a "
        "remote_actor run",
    )  # fmt: skip
    parser.add_argument("--probes", action="store_true", help="Stop robot at STOP_AT; SIGKILL at the end")
    parser.add_argument(
        "--with-help", choices=HELP_KINDS, default="none",
        help="an automated person's hands: none (default), or take-overs now and then (bench/helping_person.py)",
    )  # fmt: skip
    parser.add_argument("--seed", type=int, default=None, help=argparse.SUPPRESS)  # (one seed, in its own process;
    # --seeds is then ignored)
    parser.add_argument("--evaluate", nargs=4, metavar=("POLICY", "OUT", "DONE", "SIZE"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.evaluate:
        *paths, size = args.evaluate
        evaluate_policies(*(Path(value) for value in paths), image_size=int(size))
        return 0
    if args.seed is not None:
        run_seed(args, args.seed, args.out / f"seed{args.seed}")
        return 0
    seeds, running, rows = parse_seeds(args.seeds), {}, []
    if args.report:
        rows = [keep_figures(args.csv, args.out / f"seed{seed}" / "figures.json") for seed in seeds]
        seeds = []
    try:  # (interrupted: each running seed is stopped, its own processes with it)
        while seeds or running:
            while seeds and len(running) < args.parallel:
                seed = seeds.pop(0)
                (args.out / f"seed{seed}").mkdir(parents=True, exist_ok=True)
                log = (args.out / f"seed{seed}" / "bench.log").open("w")
                running[seed] = subprocess.Popen([sys.executable, __file__, *sys.argv[1:], "--seed", str(seed)],
                                                 stdout=log, stderr=subprocess.STDOUT)  # fmt: skip
                print(f"seed {seed} started: {args.out / f'seed{seed}'}", flush=True)
            for seed, process in list(running.items()):
                if process.poll() is not None:
                    del running[seed]
                    figures_file = args.out / f"seed{seed}" / "figures.json"
                    if process.returncode == 0 and figures_file.exists():
                        rows.append(keep_figures(args.csv, figures_file))
                    print(f"seed {seed} ended ({process.returncode})", flush=True)
            time.sleep(2.0)
    finally:
        stop_all(list(running.values()))
    print("| seed | preset | help | steps to 90% | queries | updates per step | person minutes |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for row in rows:
        steps = row["steps_to_target"] or f"not reached ({row['env_steps']})"
        print(f"| {row['seed']} | {row['preset']} | {row['help']} | {steps} | {row['queries']} | "
              f"{row['updates_per_step']} | {row['person_minutes']} |")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
