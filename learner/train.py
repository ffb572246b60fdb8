"""Training one run: the loop of Alg. 2, a runner that executes it, and a `Trainer` that is the algorithm.

How the loop executes is chosen once, here (`open_runner`): simulated envs in lockstep with the updates
(learner/lockstep.py), or a robot in real time (learner/real_time.py). Either hands `train` its env steps;
what each step means (the replay, f_psi, queries, evaluation, checkpoints) is learner/trainer.py's.
"""

import threading
from pathlib import Path
from typing import Protocol

from contract.config import TrainConfig
from contract.store import Run, Store
from learner.checkpoint import checkpoint_url as checkpoint_location
from learner.lockstep import LockstepRunner
from learner.real_time import RealTimeRunner, runs_in_real_time
from learner.run_control import Counters, Outcome, RunControl
from learner.trainer import EnvEpisode, EnvStep, Trainer

__all__ = ["Outcome", "Runner", "Trainer", "config_for_run", "open_runner", "train", "train_run"]


class Runner(Protocol):
    """How a run's env steps are taken: what `train` asks of LockstepRunner and RealTimeRunner."""

    trainer: Trainer

    def start(self, *, resumed: bool) -> None:
        """The first episodes begin (the checkpoint, if any, is read)."""
        ...

    def steps(self, count: int) -> list[EnvStep]:
        """Up to `count` env steps, with the SAC updates due for them; none when the loop should look at its
        controls first."""
        ...

    def begin_episode(self, episode: EnvEpisode) -> None:
        """The next episode of that env, its last one having ended."""
        ...

    def close(self) -> None: ...


def train(runner: Runner) -> str:
    """Alg. 2 to the run's total_steps (or a stop, an interrupt, a loss): the Outcome."""
    trainer = runner.trainer
    with trainer.control.heartbeats():
        resumed = trainer.set_up()
        if resumed is None:
            return trainer.stop_or_lost()
        runner.start(resumed=resumed)
        trainer.begin_training(resumed=resumed)
        while trainer.counters.step < trainer.config.total_steps:
            outcome = trainer.check_control()
            if outcome is not None:
                return outcome
            for step in runner.steps(trainer.steps_this_batch()):
                if trainer.record_step(step):
                    runner.begin_episode(step.episode)
                trainer.after_step()
        return trainer.finish()


def open_runner(
    config: TrainConfig, *, store: Store, run_id: int, worker: str, goal_set_id: int | None,
    checkpoint_file: Path | str, interrupt: threading.Event | None = None,
) -> Runner:  # fmt: skip
    """The run's runner, with its Trainer: real time for a robot, else lockstep."""
    control = RunControl(
        store, run_id=run_id, worker=worker, counters=Counters(), heartbeat_seconds=config.heartbeat_seconds,
        interrupt=interrupt or threading.Event(),
    )  # fmt: skip
    kind = RealTimeRunner if runs_in_real_time(config, store) else LockstepRunner
    return kind(config, store=store, control=control, goal_set_id=goal_set_id, checkpoint_file=checkpoint_file)


def config_for_run(run: Run) -> TrainConfig:
    """The run's stored config (its columns and its JSON, Run.config_values)."""
    return TrainConfig.from_dict(run.config_values())


def train_run(
    store: Store, run: Run, *, checkpoint_url: Path | str, worker: str, interrupt: threading.Event | None = None
) -> str:
    """Train a claimed run to its end, a stop, an interrupt (re-queued) or its loss to another worker.
    `checkpoint_url`: the directory or fsspec URL (s3://bucket/prefix) under which each run has its checkpoint."""
    runner = open_runner(
        config_for_run(run), store=store, run_id=run.id, worker=worker, goal_set_id=run.goal_set_id,
        checkpoint_file=checkpoint_location(checkpoint_url, run.id), interrupt=interrupt,
    )  # fmt: skip
    try:
        return train(runner)
    finally:
        runner.close()
