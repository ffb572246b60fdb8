"""The whole training loop against its update bound: is the loop as fast as its SAC updates allow?

    MUJOCO_GL=egl python bench/loop_speed.py [--steps 3000] [--task pusher] [--threads N] [--set FIELD=VALUE ...]

Runs the real loop (`learner.train.train` with the lockstep runner: env, replay, f_psi scoring of every observation,
queries posted to a real SQLite store and answered from another thread, the classifier's epochs, evaluations,
metrics, heartbeats)
for `--steps` env steps after the 1,000-step random warm-up, on the default configuration (or with `--set`'s
fields changed, as in bench/learn.py). It times the SAC updates inside that same run (sampling, rewards f_psi(s')
and the update itself), so both figures share the machine's state:

    E = env steps per second of the loop from the warm-up's end to the last step, everything included (the run's
        final checkpoint is not the loop's);
    U = updates per second of the SAC updates alone (the bound: updates_per_step updates per env step);
    R = E x updates_per_step / U, the share of the update bound the loop reaches.

On the CPU the updates run on the update thread while the loop's thread acts, steps the envs and scores query
candidates (TrainConfig.update_thread), and f_psi's epoch runs there while the evaluation runs.
The lines before the last say how long each part took per env step: the loop thread's parts, then parts timed
wherever they run (inside those), and the seconds of gradient steps (SAC's and f_psi's) per second of the loop,
which can pass 1 when they run on both threads at once.
Take `--steps` as a multiple of the epoch (1,000 env steps) so that each epoch's classifier training and
evaluation count once per 1,000 steps.

The last line reads `loop: E env steps/s end to end, U updates/s update-bound, ratio R`. Before it, the loop's
time outside the updates is split by part (ms per env step).

With `--device cuda` the updates are asynchronous (CUDA graphs on the device pipeline), so the time spent in them
is not their cost: U is then measured after the loop, on the run's own replay, networks and graphs, as updates
per second of the update alone with the GPU synchronised at both ends.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch  # noqa: E402

from app.demo import add_simulated_goal_set  # noqa: E402
from app.migrate import upgrade  # noqa: E402
from bench.learn import parse_overrides  # noqa: E402
from contract.config import TrainConfig  # noqa: E402
from contract.store import Store  # noqa: E402
from learner.networks import resolve_precision  # noqa: E402
from learner.train import open_runner, train  # noqa: E402
from learner.trainer import Trainer  # noqa: E402
from sim import TASKS  # noqa: E402

WARM_UP = 1000


class PartTimer:
    """Wall seconds spent in chosen methods of the trainer once switched on. A call made inside another timed
    call on the same thread (acting during an evaluation) counts for the outer one only; an `inner` part is timed
    wherever it runs (the updates on the update thread, the env's step inside the loop's step-and-update part)
    and is a share of another part, not a part of its own."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.inner_seconds: dict[str, float] = defaultdict(float)
        self.on = False  # switched on at the end of the warm-up
        self.local = threading.local()

    def wrap(self, owner: Any, name: str, part: str, inner: bool = False) -> None:
        original: Callable[..., Any] = getattr(owner, name)
        seconds = self.inner_seconds if inner else self.seconds

        def timed(*args: Any, **kwargs: Any) -> Any:
            inside = getattr(self.local, "inside", False)
            if not self.on or (inside and not inner):
                return original(*args, **kwargs)
            self.local.inside = True
            start = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                seconds[part] += time.perf_counter() - start
                self.local.inside = inside

        setattr(owner, name, timed)


def answer_everything(store: Store, run_id: int, done: threading.Event) -> None:
    """A labeller that answers each pending query from its ground truth, as `raq oracle` does."""
    while not done.wait(0.5):
        for query in store.pending_queries(run_id=run_id):
            store.answer_query(query_id=query.id, success=bool(query.ground_truth_success), labeler="bench")


def cuda_update_rate(trainer: Trainer, count: int) -> float:
    """Updates per second of `count` of the run's own updates with the GPU synchronised before and after."""
    torch.cuda.synchronize()
    start = time.perf_counter()
    for _ in range(count):
        trainer.updates.sac_update()
    torch.cuda.synchronize()
    return count / (time.perf_counter() - start)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=3000, help="env steps timed after the warm-up")
    parser.add_argument("--task", choices=sorted(TASKS), default="pusher")
    parser.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: torch's)")
    parser.add_argument("--query-every", type=int, default=1000, help="a query every this many env steps")
    parser.add_argument("--device", default="cpu", help="the learner's torch device (cpu, cuda)")
    parser.add_argument("--envs", type=int, default=1, help="training envs in lockstep (TrainConfig.num_envs)")
    parser.add_argument("--set", nargs="*", default=[], metavar="FIELD=VALUE", help="other TrainConfig fields")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    config = TrainConfig(
        env_id=TASKS[args.task], total_steps=WARM_UP + args.steps, query_every=args.query_every,
        query_budget=1000, checkpoint_every=10**9, device=args.device, num_envs=args.envs,
        **parse_overrides(args.set),
    )  # fmt: skip
    overrides = " ".join(args.set)
    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} threads, {config.env_id}, "
        f"{'default config' + (f' but {overrides}' if overrides else '')}, "
        f"precision {config.precision} -> {resolve_precision(config.precision, torch.device(args.device).type)}; "
        f"{args.steps} env steps timed on {args.device}, {args.envs} env(s) in lockstep",
        flush=True,
    )
    with tempfile.TemporaryDirectory() as tmp:
        url = f"sqlite:///{Path(tmp) / 'raq.sqlite3'}"
        upgrade(url)
        store = Store(url)
        goal_set_id = add_simulated_goal_set(store, task=args.task, name="goals", count=10)
        run = store.create_run(
            env_id=config.env_id, algorithm=config.algorithm, config=config.to_dict(), seed=0,
            goal_set_id=goal_set_id, total_steps=config.total_steps,
        )  # fmt: skip
        store.claim_next_run(worker="bench")
        runner = open_runner(
            config, store=store, run_id=run.id, worker="bench", goal_set_id=goal_set_id,
            checkpoint_file=Path(tmp) / "checkpoint.pt",
        )  # fmt: skip
        trainer = runner.trainer
        timer = PartTimer()
        timer.wrap(runner, "steps", "acting, env steps and SAC updates")
        timer.wrap(trainer, "_end_of_epoch", "epoch ends and evaluations")
        timer.wrap(trainer, "_evaluate", "epoch ends and evaluations")
        timer.wrap(trainer, "_observe", "query candidates")
        timer.wrap(trainer.queries, "ask", "queries asked")
        timer.wrap(trainer, "_log", "metrics")
        timer.wrap(runner, "_actions", "acting", inner=True)
        for episode in runner.episodes:
            timer.wrap(episode.env, "step", "env steps", inner=True)
        timer.wrap(trainer.queries, "score_pending", "query scoring", inner=True)
        timer.wrap(trainer, "sac_updates", "SAC updates", inner=True)
        timer.wrap(trainer, "_classifier_steps", "classifier steps", inner=True)
        timer.wrap(trainer.evaluator, "run_episodes", "evaluation episodes", inner=True)
        started: list[float] = []
        ended: list[float] = []
        original_after_step = trainer.after_step

        def after_step() -> None:
            original_after_step()
            if trainer.counters.step == WARM_UP:
                timer.on = True
                started.append(time.perf_counter())
            if trainer.counters.step == config.total_steps:  # (the run's end: its final checkpoint is not the loop)
                timer.on = False
                ended.append(time.perf_counter())

        trainer.after_step = after_step  # type: ignore[method-assign]
        done = threading.Event()
        labeller = threading.Thread(target=answer_everything, args=(store, run.id, done), daemon=True)
        labeller.start()
        update_rate = 0.0
        try:
            train(runner)
            elapsed = ended[0] - started[0]
            print(f"updates: {trainer.updates.describe()}")
            if trainer.agent.device.type == "cuda":
                update_rate = cuda_update_rate(trainer, count=min(args.steps, 1000))
        finally:
            done.set()
            labeller.join()
            runner.close()
            store.dispose()
    steps = args.steps
    update_seconds = timer.inner_seconds["SAC updates"]
    e = steps / elapsed
    u = update_rate if args.device.startswith("cuda") else steps * config.updates_per_step / update_seconds
    print("ms per env step: " + ", ".join(f"{part} {1000 * s / steps:.1f}" for part, s in timer.seconds.items()))
    if runner.update_thread is None:
        where = "the updates after the envs step, f_psi's epochs at once"
    else:
        where = "the updates on the update thread while the loop's thread acts, steps the envs and scores; "
        where += "f_psi's epoch on the update thread while the evaluation runs"
    print(
        "timed wherever they run, ms per env step: "
        + ", ".join(f"{part} {1000 * s / steps:.1f}" for part, s in timer.inner_seconds.items())
        + f" ({where})"
    )
    other = elapsed - sum(timer.seconds.values())
    print(f"ms per env step outside the timed parts (replay, bookkeeping, heartbeats): {1000 * other / steps:.1f}")
    if not args.device.startswith("cuda"):  # (on a GPU the time spent in the updates is not their cost)
        training = update_seconds + timer.inner_seconds["classifier steps"]
        print(f"gradient steps (SAC and f_psi) per second of the loop's time: {training / elapsed:.2f}")
    ratio = e * config.updates_per_step / u
    print(f"loop: {e:.1f} env steps/s end to end, {u:.1f} updates/s update-bound, ratio {ratio:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
