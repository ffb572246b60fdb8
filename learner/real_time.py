"""The real-time runner: a robot (or any env given a control_hz) steps at its own rate in an actor that never waits for
the learner; the learner takes the actor's steps as they come and runs SAC updates while none waits.

A robot is driven only by its own process (`raq robot ENV`, robot/drive/process.py): the learner links to it and
waits for it, never making the env; another env given a control_hz is stepped by a process the learner starts beside
itself. Either is linked through the database and the checkpoint store (learner/actor_handle.py). There are no
evaluation envs: a robot is not opened twice. A person's Evaluate now episodes run on the robot itself and are asked
about (learner/robot_evaluation.py).

The actor's steps stay in the store until a checkpoint holds them: a learner that takes such a run over adds those
after its checkpoint (an earlier learner's, or posted as it died) to its replay and its step count, in order, before
the actor starts again, so that no step the robot took is lost.
"""

import time
from collections import deque
from pathlib import Path

import numpy as np

from contract.actor_messages import ActorMessage, ActorSettings, EpisodeStart, StateChange, SuccessMarked, Transition
from contract.config import TrainConfig
from contract.envs import model_image
from contract.learner_pace import PACE_METRIC
from contract.store import Store
from learner.actor_handle import ActorProcess, RemoteActor
from learner.robot_evaluation import RobotEvaluation
from learner.run_control import RunControl
from learner.trainer import EnvEpisode, EnvStep, Trainer
from robot.base import control_rate, robot_class

SUCCESS_FRAMES = 3
"""The last frames of an episode a person marked a success that join f_psi's positives."""
REAL_TIME_SLICE = 0.5
"""Seconds the loop waits for the actor's next step before it looks at its controls again."""
ACTOR_POLL_SECONDS = 0.02
"""How long one wait for the actor's next message lasts once the updates are as many as allowed."""


def runs_in_real_time(config: TrainConfig, store: Store) -> bool:
    """The run's env steps in real time: a robot env (by its class, or one registered by a factory function whose
    robot process is up), one given a control_hz, or an actor on another host."""
    if config.remote_actor or control_rate(config.env_id, config.control_hz) > 0:
        return True
    return robot_class(config.env_id) is None and store.robot_process_of(env_id=config.env_id) is not None


class RealTimeRunner:
    """Takes the actor's steps and fits the SAC updates between them; owns the actor."""

    def __init__(
        self, config: TrainConfig, *, store: Store, control: RunControl, goal_set_id: int | None,
        checkpoint_file: Path | str,
    ) -> None:  # fmt: skip
        execution = config.execution
        self.claim = store.run_claim(run_id=control.run_id)  # (the learner's, read as it set the run up)
        self.actor: RemoteActor
        if execution.remote_actor or robot_class(config.env_id) is not False:
            # the robot's own process drives it (`raq robot`, `raq actor`): the env is never made here
            self.actor = RemoteActor(
                store, run_id=control.run_id, claim=self.claim, checkpoint_file=str(checkpoint_file),
                heartbeat=control.tick,
            )  # fmt: skip
        else:
            settings = ActorSettings(
                config.to_dict(), run_id=control.run_id, database_url=store.url,
                control_hz=control_rate(config.env_id, execution.control_hz),
                person_reset=execution.reset_every_episode,
            )  # fmt: skip
            self.actor = ActorProcess(
                store, settings, claim=self.claim, checkpoint_file=str(checkpoint_file), heartbeat=control.tick
            )
        self.episode = EnvEpisode(self.actor, length=-1)  # (none until the actor's first, or the checkpoint's)
        self.trainer = trainer = Trainer(
            config, store=store, control=control, goal_set_id=goal_set_id, checkpoint_file=checkpoint_file,
            episodes=[self.episode], eval_envs=[],
        )  # fmt: skip
        # a person's Evaluate now episodes, their last frames asked about outside the query budget
        self.evaluation = RobotEvaluation(
            config.task, config.evaluation, store=store, run_id=control.run_id, reward_model=trainer.reward_model,
            counters=trainer.counters, control=control, reads_answers=trainer.queries is None,
        )  # fmt: skip
        if trainer.queries is not None:
            trainer.queries.on_answers = self.evaluation.answers_read
        self.policy_sync_seconds, self.initial_random_steps = execution.policy_sync_seconds, config.initial_random_steps
        self.updates_per_step = config.updates_per_step
        self.policy_sent_at = -np.inf
        self.periods: list[float] = []
        self.person_steps: list[bool] = []  # (whether a person drove each step since the last record)
        self.last_frames: deque[np.ndarray] = deque(maxlen=SUCCESS_FRAMES)  # the episode's newest observations
        self.previous_frames: list[np.ndarray] = []  # the last ones of the episode before
        self.paced_from = (0, 0)  # (env step, SAC updates) at the last record
        self.kept_from, self.kept_through = 0, 0  # (the checkpoint's step; the id of the newest message kept since)
        self.actor_started = False
        trainer.metric_sources.extend([self._period_metrics, self._pace_metrics, self._person_metrics])
        trainer.after_checkpoint.append(self._forget_checkpointed)

    def start(self, *, resumed: bool) -> None:
        """The actor may begin (it resets the scene itself, a person first when needed) once `steps` has handed
        over the actor's steps kept since the checkpoint."""
        counters = self.trainer.counters
        self.kept_from, self.paced_from = counters.step, (counters.step, counters.total_updates)
        self.kept_through = self.actor.resume(counters.actor_message)
        self._start_actor_when_kept_are_taken()

    def _start_actor_when_kept_are_taken(self) -> None:
        """The actor may begin at the run's step, every kept step counted."""
        if self.actor_started or self.actor.taken < self.kept_through:
            return
        counters = self.trainer.counters
        if counters.step > self.kept_from:
            self.trainer.control.event(
                f"{counters.step - self.kept_from} robot steps taken after step {self.kept_from} (kept in the store "
                f"since the last checkpoint) added to the replay; the actor starts at step {counters.step}"
            )
        self.paced_from = (counters.step, counters.total_updates)
        self.actor.start(counters.step, self.claim)
        self.actor_started = True

    def _next_message(self, timeout: float) -> ActorMessage | None:
        """The actor's next message (the kept ones first), counted as taken."""
        message = self.actor.next_message(timeout)
        if message is not None:
            self.trainer.counters.actor_message = self.actor.taken
        return message

    def _forget_checkpointed(self) -> None:
        """A checkpoint holds the actor's messages up to the last taken: the store forgets them."""
        self.actor.checkpointed(self.trainer.counters.actor_message)

    def begin_episode(self, episode: EnvEpisode) -> None:
        """The actor begins the next episode itself; its first observation is a message `steps` takes."""
        episode.length = -1  # (no episode until that message)

    def steps(self, count: int) -> list[EnvStep]:
        """The actor's next step, and SAC updates while none is waiting (at most updates_per_step for each step
        taken; fewer when the updates are slower than the robot); the policy sent every policy_sync_seconds. An
        episode's first observation is taken on the way; the steps kept since the checkpoint come first. Nothing
        after REAL_TIME_SLICE seconds without a step (a person resetting, a stopped robot), so that the loop sees
        its stop and interrupt meanwhile."""
        trainer, episode = self.trainer, self.episode
        deadline = time.monotonic() + REAL_TIME_SLICE
        while True:
            self._start_actor_when_kept_are_taken()
            self._send_policy()
            message = self._next_message(0.0)  # the actor's steps first: the replay never lags the robot
            if message is None and trainer.counters.total_updates < trainer.updates_due_by(trainer.counters.step):
                trainer.sac_updates(1)
                continue
            if message is None:
                message = self._next_message(ACTOR_POLL_SECONDS)
            if message is None:
                if time.monotonic() >= deadline:
                    trainer.control.tick()
                    return []
            elif isinstance(message, EpisodeStart):
                trainer.start_episode(episode, message.observation, message.info)
                self.evaluation.episode_began()
                self.previous_frames = list(self.last_frames)
                self.last_frames.clear()
            elif isinstance(message, SuccessMarked):
                self._success_marked()
            elif isinstance(message, StateChange):
                trainer.control.event(f"robot: {message.state}")
            elif isinstance(message, Transition) and episode.length >= 0:  # a step of the episode under way
                if message.period is not None:
                    self.periods.append(message.period)
                self.evaluation.take_step(message, env_step=trainer.counters.step + 1)
                self.person_steps.append(message.person)
                self.last_frames.append(message.observation)
                action = np.asarray(message.action, dtype=np.float32)
                return [EnvStep(episode, action, message.outcome(), message.person)]

    def _send_policy(self) -> None:
        """pi's weights to the actor, every policy_sync_seconds once the warm-up is over."""
        now = time.monotonic()
        warming_up = self.trainer.counters.step < self.initial_random_steps
        if warming_up or now - self.policy_sent_at < self.policy_sync_seconds:
            return
        modules = self.trainer.policy_state()["agent"]
        self.actor.send_policy({name: {key: value.detach().cpu() for key, value in state.items()}
                                for name, state in modules.items()})  # fmt: skip
        self.policy_sent_at = now

    def _period_metrics(self) -> dict[str, float]:
        """The actor's control period as it kept it since the last record."""
        if not self.periods:
            return {}
        periods = np.asarray(self.periods) * 1000.0
        self.periods.clear()
        return {"actor/period_ms_mean": float(periods.mean()), "actor/period_ms_p99": float(np.percentile(periods, 99)),
                "actor/period_ms_max": float(periods.max())}  # fmt: skip

    def _success_marked(self) -> None:
        """A person's success key: the last frames of the episode under way (of the one before, when this one has
        barely begun: the key came as it ended) join f_psi's positives, as a yes answer's frame does."""
        frames = list(self.last_frames) if len(self.last_frames) > 1 else self.previous_frames
        model = self.trainer.reward_model
        if model is None or not frames:
            self.trainer.control.event("a success was marked, but this run has no classifier to tell")
            return
        for frame in frames:
            model.add_positive(model_image(frame, self.trainer.config.image_size, self.trainer.config.env_id))
        self.trainer.control.event(f"a person marked a success: the episode's last {len(frames)} frames are positives")

    def _person_metrics(self) -> dict[str, float]:
        """The share of the robot's steps since the last record that a person drove by hand, and how many steps
        they have driven in all (those the replay holds)."""
        if not self.person_steps:
            return {}
        share = float(np.mean(self.person_steps))
        self.person_steps.clear()
        return {"person/step_share": share, "person/steps": float(len(self.trainer.replay.person_indices()))}

    def _pace_metrics(self) -> dict[str, float]:
        """SAC updates per robot step since the last record, over the steps after the warm-up (none is due
        before); nothing while the interval had none of those steps."""
        trainer, counters = self.trainer, self.trainer.counters
        (step, updates), (last_step, last_updates) = (counters.step, counters.total_updates), self.paced_from
        self.paced_from = (step, updates)
        training_steps = (trainer.updates_due_by(step) - trainer.updates_due_by(last_step)) / self.updates_per_step
        return {PACE_METRIC: (updates - last_updates) / training_steps} if training_steps > 0 else {}

    def close(self) -> None:
        self.actor.close()
