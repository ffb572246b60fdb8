"""The training loop of one run: SAC from pixels with the run's reward method, reading and writing only the Store.

Per environment step t -> t+1 (Alg. 2): act (uniformly at random for the first initial_random_steps), step the
env while updates_per_step SAC updates run on the update thread (after the warm-up; on the replay as it was before
the step), store (s_t, a_t, s_{t+1}), offer s_{t+1} as a query candidate; then, at their intervals: read answers,
train f_psi (epoch ends), evaluate, ask a query, record metrics, checkpoint, heartbeat.

With the update thread (the CPU's default) the loop's thread does beside each batch's updates what does not need
them done: acting (on a copy of pi synced before the updates start: the same pi the step would act with), the env
steps, scoring the query candidates waiting for a batch (f_psi is not the updates' to change). At an epoch's end
f_psi trains on the update thread while the evaluation's episodes run on the loop's thread (they read pi only).

With a robot env (or control_hz set) the env runs in real time instead, in an actor process (learner/actor.py):
the loop takes its steps as they come and runs the SAC updates while none is waiting. With remote_actor that
actor runs on the robot's host (`raq actor`), linked through the database and the checkpoint store
(learner/actor_link.py).

Reward timing: the transition (s_t, a_t, s_{t+1}) is rewarded r = f_psi(s_{t+1}) (sparse: success(s_{t+1})),
so the action that reaches the goal is the one credited; Alg. 2 writes r(s_t) but the state it means is the
outcome of the step. Episodes end on the time limit only (no terminal on success), so SAC bootstraps through.
"""

import contextlib
import functools
import json
import math
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import torch

from contract.algorithms import ALGORITHM_SPECS
from contract.checkpoint_location import (
    BEST_POLICY_FILENAME,
    LAST_EVAL_POLICY_FILENAME,
    POLICIES_INDEX,
    POLICY_FILENAME,
    sibling,
)
from contract.config import TrainConfig
from contract.envs import (
    check_action_space,
    control_rate,
    display_image,
    display_of_snapshot,
    make_env,
    model_image,
    scale_action,
    snapshot_of,
    success_of,
)
from contract.images import decoded_array, model_array
from contract.store import Run, RunPhase, RunStatus, Store
from learner.actor import ActorProcess, ActorSettings
from learner.actor_link import RemoteActor
from learner.checkpoint import checkpoint_url as checkpoint_location
from learner.checkpoint import load_checkpoint, load_json, save_checkpoint, save_json
from learner.env_workers import ProcessEnv, process_envs
from learner.evaluation import Evaluator, eval_env_count
from learner.exploration import EpisodeNoise, warm_up_action
from learner.networks import resolve_precision
from learner.query_channel import QueryChannel
from learner.replay import ReplayBuffer
from learner.reward import RewardModel
from learner.robot_evaluation import RobotEvaluation
from learner.run_control import Counters, Outcome, RunControl
from learner.sac import SACAgent
from learner.updates import HostUpdates, make_updates

__all__ = ["Outcome", "Trainer", "config_for_run", "train_run"]
CHECKPOINT_VERSION = 1
REAL_TIME_SLICE = 0.5
"""Real time: seconds the loop waits for the actor's next step before it looks at its controls again."""
ACTOR_POLL_SECONDS = 0.02
"""Real time: how long one wait for the actor's next message lasts once the updates are as many as allowed."""


def config_for_run(run: Run) -> TrainConfig:
    """The run's stored config (its columns and its JSON, Run.config_values)."""
    return TrainConfig.from_dict(run.config_values())


def train_run(
    store: Store, run: Run, *, checkpoint_url: Path | str, worker: str, interrupt: threading.Event | None = None
) -> str:
    """Train a claimed run to its end, a stop, an interrupt (re-queued) or its loss to another worker.
    `checkpoint_url`: the directory or fsspec URL (s3://bucket/prefix) under which each run has its checkpoint."""
    trainer = Trainer(
        config_for_run(run), store=store, run_id=run.id, worker=worker, goal_set_id=run.goal_set_id,
        checkpoint_file=checkpoint_location(checkpoint_url, run.id), interrupt=interrupt,
    )  # fmt: skip
    try:
        return trainer.train()
    finally:
        trainer.close()


class Trainer:
    """One run's state and loop. Public: train() -> Outcome; close()."""

    def __init__(
        self, config: TrainConfig, *, store: Store, run_id: int, worker: str, goal_set_id: int | None,
        checkpoint_file: Path | str, interrupt: threading.Event | None = None,
    ) -> None:  # fmt: skip
        self.config, self.store, self.run_id = config, store, run_id
        self.goal_set_id, self.checkpoint_file = goal_set_id, checkpoint_file
        self.spec = ALGORITHM_SPECS[config.algorithm]
        self.counters = Counters()
        self.control = RunControl(
            store, run_id=run_id, worker=worker, counters=self.counters, heartbeat_seconds=config.heartbeat_seconds,
            interrupt=interrupt or threading.Event(),
        )  # fmt: skip
        torch.manual_seed(config.seed)
        self.rng = np.random.default_rng(config.seed)
        size = config.image_size
        # how the loop executes is chosen here, once: a real-time actor, or envs stepped in lockstep with updates
        self.actor: ActorProcess | RemoteActor | None = None
        if config.remote_actor:  # on the robot's host: the env is neither made nor imported here
            self.actor = RemoteActor(
                store, run_id=run_id, checkpoint_file=str(checkpoint_file), heartbeat=self.control.tick
            )
            envs: list[Any] = [self.actor]
        elif control_hz := control_rate(config.env_id, config.control_hz):
            settings = ActorSettings(
                config.to_dict(), run_id=run_id, database_url=store.url, control_hz=control_hz,
                person_reset=config.reset_every_episode,
            )  # fmt: skip
            self.actor = ActorProcess(settings)
            envs = [self.actor]
        elif config.env_processes:
            envs = process_envs(config.num_envs, config.env_id, image_size=size, display_size=config.display_size)
        else:
            envs = [make_env(config.env_id, image_size=size, display_size=config.display_size)
                    for _ in range(config.num_envs)]  # fmt: skip
        self.episodes = [EnvEpisode(env) for env in envs]
        self.env = self.episodes[0].env
        self.eval_envs = [  # their renders are the rollout's frames only: drawn at that size (2 ms, not 5)
            make_env(config.env_id, image_size=size, display_size=config.rollout_size)
            for _ in range(eval_env_count(config) if self.actor is None else 0)  # (a robot is not opened twice)
        ]
        self.action_space = check_action_space(self.env)
        self.action_dim = int(self.action_space.shape[0])
        self.agent = SACAgent(config, self.action_dim)
        self.replay = ReplayBuffer(config.replay_capacity, (size, size, 3), self.action_dim, envs=config.num_envs)
        self.reward_model = RewardModel(config, self.rng) if self.spec.classifier else None
        asks = self.spec.queries and self.reward_model is not None
        # real time: a person's Evaluate now episodes, their last frames asked about outside the query budget
        self.robot_evaluation = None if self.actor is None else RobotEvaluation(
            config, store=store, run_id=run_id, reward_model=self.reward_model, counters=self.counters,
            control=self.control, reads_answers=not asks,
        )  # fmt: skip
        self.queries: QueryChannel | None = None
        if asks and self.reward_model is not None:
            self.queries = QueryChannel(
                config, store=store, run_id=run_id, reward_model=self.reward_model, counters=self.counters,
                control=self.control,
                on_answers=None if self.robot_evaluation is None else self.robot_evaluation.answers_read,
            )  # fmt: skip
        self.updates = make_updates(
            config, agent=self.agent, replay=self.replay, reward_model=self.reward_model, spec=self.spec, rng=self.rng
        )  # fmt: skip
        evaluation = config if self.actor is None else replace(config, eval_episodes=0)
        self.evaluator = Evaluator(
            evaluation, envs=self.eval_envs, agent=self.agent, reward_model=self.reward_model, store=store,
            run_id=run_id, control=self.control,
        )  # fmt: skip
        self.update_thread = (
            ThreadPoolExecutor(max_workers=1, thread_name_prefix="sac-updates")
            if uses_update_thread(config, self.agent.device) and self.actor is None
            else None
        )
        self._step_batch = self._step_envs_and_update if self.actor is None else self._real_time_steps
        self._begin = self._begin_episode if self.actor is None else self._await_actor_episode
        self.actor_periods: list[float] = []
        self.policy_sent_at = -math.inf
        # with the update thread, on the host pipeline, an epoch's f_psi steps run on the update thread while the
        # loop's thread evaluates
        self.classifier_beside_evaluation = self.update_thread is not None and isinstance(self.updates, HostUpdates)
        # acting draws from its own generator; with the update thread it acts on a copy of pi (synced per batch)
        self.acting_generator = torch.Generator(device=self.agent.device).manual_seed(config.seed)
        self.acting_copy = self.agent.policy_copy(self.acting_generator) if self.update_thread is not None else None
        if config.exploration_noise_beta > 0:  # each env's coloured eps, from the acting generator (else i.i.d.)
            for episode in self.episodes:
                episode.noise = EpisodeNoise(
                    config.exploration_noise_beta, config.episode_steps, self.action_dim, self.acting_generator
                )
        self.finished_returns: list[float] = []
        self.finished_successes: list[float | None] = []
        self.log_time, self.log_step, self.log_updates = time.monotonic(), 0, 0

    # ================================================================== the loop
    def train(self) -> str:
        """Alg. 2, one env step at a time; what is due at a step's interval happens after it (`_after_step`). With
        num_envs > 1 the policy acts for all envs in one batch, then each env's step is one step of the loop."""
        cfg, counters = self.config, self.counters
        resumed = self._set_up()
        if resumed is None:
            return self._stop_or_lost()
        if self.actor is not None:
            self.actor.start(counters.step)
        for index, episode in enumerate(self.episodes):
            self._begin(episode, seed=None if resumed else env_seed(cfg.seed, index))
        if resumed:
            self._redo_interrupted_work()
        self.control.set_phase(self._loop_phase())
        self.log_time, self.log_step, self.log_updates = time.monotonic(), counters.step, counters.total_updates
        # the ETA is taken from the training phase's speed only (the random warm-up runs several times faster)
        self.training_since = (self.log_time, counters.step) if counters.step >= cfg.initial_random_steps else None
        while counters.step < cfg.total_steps:
            outcome = self._check_control()
            if outcome is not None:
                return outcome
            episodes = self.episodes[: self._envs_this_batch()]
            for episode, action, env_outcome in self._step_batch(episodes):
                self._record_step(episode, action, env_outcome)
                self._after_step()
        return self._finish()

    def _envs_this_batch(self) -> int:
        """All envs, but no step past the next checkpoint (a higher-priority run may be waiting: the control
        check comes right after it) or the end of the run."""
        cfg, step = self.config, self.counters.step
        return min(len(self.episodes), cfg.total_steps - step, cfg.checkpoint_every - step % cfg.checkpoint_every)

    def _step_envs_and_update(self, episodes: "list[EnvEpisode]") -> list[tuple["EnvEpisode", np.ndarray, tuple]]:
        """The envs' actions and steps (physics and render in one burst: on a GPU not between the update graphs)
        and the SAC updates due for these steps: on the update thread while the loop's thread acts, steps the envs
        and scores waiting query candidates (MuJoCo leaves the GIL, so a second core does that), else right after
        the steps. The updates sample the replay as it was before these steps."""
        count = self._updates_due(len(episodes))
        beside = self.update_thread is not None and count > 0
        if self.acting_copy is not None:
            self.acting_copy.sync()  # pi as the last batch's updates left it (none is running now)
        # the warm-up's uniform actions come from the run's generator, which the updates draw from: before them
        warm_up = self.counters.step < self.config.initial_random_steps
        actions = self._actions(episodes) if warm_up or not beside else None
        pending: Future[None] | None = None
        if beside:
            assert self.update_thread is not None
            pending = self.update_thread.submit(self._sac_updates, count)
        try:
            if actions is None:
                actions = self._actions(episodes)
            outcomes = self._simulate(episodes, actions)
            if self.queries is not None:
                self.queries.score_full_batch()
        finally:
            if pending is not None:
                pending.result()  # (an update's error is raised here)
        if pending is None and count:
            self._sac_updates(count)
        return list(zip(episodes, actions, outcomes, strict=True))

    # ------------------------------------------------------------------ real time
    def _await_actor_episode(self, episode: "EnvEpisode", seed: int | None = None) -> None:
        """Real time: the actor resets the scene itself (a person first, when needed); its first observation is
        the next message `_real_time_steps` takes."""
        episode.length = -1  # (no episode until that message)

    def _real_time_steps(self, episodes: "list[EnvEpisode]") -> list[tuple["EnvEpisode", np.ndarray, tuple]]:
        """Real time: the actor's next step, and SAC updates while none is waiting (at most updates_per_step for
        each step taken; fewer when the updates are slower than the robot); the policy sent every
        policy_sync_seconds. An episode's first observation is taken on the way. Nothing
        after REAL_TIME_SLICE seconds without a step (a person resetting, a stopped robot), so that the loop sees
        its stop and interrupt meanwhile. Evaluate now's episodes are taken on the way too (`RobotEvaluation`)."""
        assert self.actor is not None and self.robot_evaluation is not None
        episode, counters = episodes[0], self.counters
        deadline = time.monotonic() + REAL_TIME_SLICE
        while True:
            self._send_policy()
            message = self.actor.next_message(0.0)  # the actor's steps first: the replay never lags the robot
            if message is None and counters.total_updates < self._updates_due_by(counters.step):
                self._sac_updates(1)
                continue
            if message is None:
                message = self.actor.next_message(ACTOR_POLL_SECONDS)
            if message is None:
                if time.monotonic() >= deadline:
                    self.control.tick()
                    return []
            elif message.kind == "reset":
                self._start_episode(episode, message.observation, message.info)
                self.robot_evaluation.episode_began()
            elif message.kind == "state":
                self.control.event(f"robot: {message.state}")
            elif episode.length >= 0:  # a step of the episode under way
                if message.period is not None:
                    self.actor_periods.append(message.period)
                outcome = (message.observation, message.reward, message.terminated, message.truncated, message.info)
                self.robot_evaluation.take_step(message, env_step=counters.step + 1)
                return [(episode, np.asarray(message.action, dtype=np.float32), outcome)]

    def _send_policy(self) -> None:
        """Real time: pi's weights to the actor, every policy_sync_seconds once the warm-up is over."""
        now = time.monotonic()
        if (
            self.counters.step < self.config.initial_random_steps
            or now - self.policy_sent_at < self.config.policy_sync_seconds
        ):
            return
        assert self.actor is not None
        modules = self._policy_state()["agent"]
        self.actor.send_policy({name: {key: value.detach().cpu() for key, value in state.items()}
                                for name, state in modules.items()})  # fmt: skip
        self.policy_sent_at = now

    def _updates_due(self, steps: int) -> int:
        """SAC updates of the next `steps` env steps: updates_per_step for each step from the warm-up's end."""
        step = self.counters.step
        return self._updates_due_by(step + steps) - self._updates_due_by(step)

    def _updates_due_by(self, step: int) -> int:
        """SAC updates due in all by env step `step`: updates_per_step for each step from the warm-up's end on."""
        return max(0, step - self.config.initial_random_steps + 1) * self.config.updates_per_step

    def _after_step(self) -> None:
        cfg, step = self.config, self.counters.step
        if self.queries is not None and (step % cfg.log_every == 0 or step % cfg.epoch_steps == 0):
            self.queries.read_answers()
        if step == cfg.initial_random_steps:
            self.control.event(f"warm-up done at step {step}: policy acting, SAC updates started")
            self.control.set_phase(RunPhase.TRAINING)
            self.training_since = (time.monotonic(), step)
        epoch_end, evaluation = step % cfg.epoch_steps == 0, step % cfg.eval_every == 0
        if epoch_end or evaluation:
            self._end_of_epoch_and_evaluation(epoch_end=epoch_end, evaluation=evaluation)
        if self.queries is not None and step % cfg.query_every == 0:
            self.queries.ask()
        if step % cfg.log_every == 0:
            self._log()
        if step % cfg.checkpoint_every == 0 and step < cfg.total_steps and not self.control.interrupted:
            self._checkpoint()  # (interrupted: the loop checkpoints at once)
            self.control.look_for_higher_priority()
        self.control.tick()

    def _set_up(self) -> bool | None:
        """Goals, checkpoint, asked queries; True when resumed from a checkpoint, None when the run is no longer
        this learner's to train."""
        cfg, control = self.config, self.control
        precision = resolve_precision(cfg.precision, self.agent.device.type)
        control.event(
            f"learner {control.worker} setting up: {cfg.algorithm} on {cfg.env_id}, {cfg.total_steps} steps, "
            f"precision {precision}"
            + (" (auto: the faster on this machine)" if cfg.precision == "auto" else "")
            + f"; {self.updates.describe()}"
        )
        stored_step = int(self.store.get_run(run_id=self.run_id).step or 0)
        # each setup phase can take long (a large checkpoint): beat after each so no one reclaims the run
        self._load_goals()
        control.tick()
        state = load_checkpoint(self.checkpoint_file)
        control.tick()
        if state is not None:
            self._restore(state)
        control.step_known = True
        control.tick()
        if self.queries is not None:
            self.queries.sync()
        if not control.beat(status=RunStatus.TRAINING):
            return None
        step = self.counters.step
        if state is not None:
            dropped = self.store.delete_metrics_after(run_id=self.run_id, step=step)
            control.event(f"resumed from checkpoint at step {step}; {dropped} metrics recorded after it were dropped")
            return True
        if stored_step > 0:
            dropped = self.store.delete_metrics_after(run_id=self.run_id, step=0)
            control.event(
                f"the run had reached step {stored_step} but no checkpoint was found at {self.checkpoint_file}: "
                f"training restarts from step 0 ({dropped} earlier metrics dropped). Checkpoints must be where all "
                "learners find them (RAQ_CHECKPOINT_URL, e.g. s3://bucket/prefix), or a run that moves to another "
                "host starts over.",
                level="warning",
            )
        if cfg.initial_random_steps:
            control.event(f"warm-up started: {cfg.initial_random_steps} uniformly random steps")
        return False

    def _redo_interrupted_work(self) -> None:
        """After a resume: what an interrupt cut short before the checkpoint (the naive classifier's one-off
        training, the evaluation of the checkpoint's step) is done now."""
        cfg, counters = self.config, self.counters
        if self.spec.train_once and not counters.naive_trained and counters.step >= cfg.epoch_steps:
            self._end_of_epoch()
        step = counters.step
        if 0 < step < cfg.total_steps and step % cfg.eval_every == 0 and counters.evaluated_step != step:
            self._evaluate()

    def close(self) -> None:
        if self.update_thread is not None:
            self.update_thread.shutdown()
        for env in (*(episode.env for episode in self.episodes), *self.eval_envs):
            with contextlib.suppress(Exception):  # closing must not hide the error that ended training
                env.close()

    def _actions(self, episodes: "list[EnvEpisode]") -> np.ndarray:
        """One action per env: uniformly random during the warm-up, else the policy's, in one batch. With coloured
        noise (exploration_noise_beta) both take each env's next eps: the warm-up's as U(-1, 1) through the CDF."""
        cfg, first = self.config, self.counters.step
        actions = np.empty((len(episodes), self.action_dim), dtype=np.float32)
        sources = [episode.noise for episode in episodes if episode.noise is not None]
        noise = torch.stack([source.next() for source in sources]) if sources else None
        random = [index for index in range(len(episodes)) if first + index < cfg.initial_random_steps]
        for index in random:
            actions[index] = warm_up_action(None if noise is None else noise[index], self.rng, self.action_dim)
        acting = [index for index in range(len(episodes)) if index not in random]
        if acting:
            observations = np.stack([episodes[index].obs for index in acting])
            eps = None if noise is None else noise[acting]
            if self.acting_copy is not None:  # (beside the updates: the copy of pi)
                actions[acting] = self.acting_copy.act_batch(observations, noise=eps)
            else:
                actions[acting] = self.agent.act_batch(observations, generator=self.acting_generator, noise=eps)
        return actions

    def _simulate(self, episodes: "list[EnvEpisode]", actions: np.ndarray) -> list[tuple]:
        """Every env's step, its physics and its camera's render (gymnasium's 5-tuple). Envs in worker processes
        (env_processes) are all sent their actions first, so they step at once."""
        scaled = [scale_action(action, self.action_space) for action in actions]
        if not self.config.env_processes:
            return [episode.env.step(action) for episode, action in zip(episodes, scaled, strict=True)]
        for episode, action in zip(episodes, scaled, strict=True):
            episode.env.step_async(action)
        return [episode.env.step_wait() for episode in episodes]

    def _record_step(self, episode: "EnvEpisode", action: np.ndarray, env_outcome: tuple) -> None:
        """One env step of the loop: its transition into the replay, the observation offered to the queries, the
        episode's end."""
        cfg = self.config
        raw, reward, terminated, truncated, info = env_outcome
        self.counters.step += 1
        episode.length += 1
        episode.total += float(reward)
        next_obs = model_image(raw, cfg.image_size, cfg.env_id)
        success = success_of(info)
        if success is None and self.spec.needs_success:
            raise ValueError(
                f"algorithm {cfg.algorithm!r} needs the env to report info['success']; {cfg.env_id} does not"
            )
        next_slot = self.replay.add_frame(next_obs)
        self.replay.add(episode.obs_slot, action, next_slot, bool(terminated), success)
        self._observe(episode.env, next_obs, info, success)  # before any reset: the display render is of s_{t+1}
        if terminated or truncated or episode.length >= cfg.episode_steps:
            self.finished_returns.append(episode.total)
            self.finished_successes.append(success)
            self._begin(episode)
        else:
            episode.obs, episode.obs_slot = next_obs, next_slot

    def _begin_episode(self, episode: "EnvEpisode", seed: int | None = None) -> None:
        raw, info = episode.env.reset(seed=seed)
        self._start_episode(episode, raw, info)

    def _start_episode(self, episode: "EnvEpisode", raw: Any, info: dict[str, Any]) -> None:
        """An episode begins at the observation `raw` of a reset."""
        episode.obs = model_image(raw, self.config.image_size, self.config.env_id)
        episode.obs_slot = self.replay.add_frame(episode.obs)
        episode.length, episode.total = 0, 0.0
        if episode.noise is not None:
            episode.noise.restart()
        self._observe(episode.env, episode.obs, info, success_of(info))

    def _observe(
        self, env: gymnasium.Env | ProcessEnv, image: np.ndarray, info: dict[str, Any], success: float | None
    ) -> None:
        """Offer a new observation to the query channel; its display render is of this same state: rendered now
        if it is kept, or later from a snapshot of the state when the env can take one (then scored in a batch)."""
        if self.queries is None or not self.queries.budget_left:
            return
        size = self.config.display_size
        snapshot = snapshot_of(env) if self.config.query_score_batch > 1 else None
        if snapshot is None:
            self.queries.observe(image, info, success, functools.partial(display_image, env, size, image))
        else:
            render = functools.partial(display_of_snapshot, env, snapshot, size, image)
            self.queries.observe(image, info, success, render, deferred=True)

    def _finish(self) -> str:
        counters = self.counters
        if counters.evaluated_step != counters.step:
            self._evaluate()
        if self.control.interrupted and counters.evaluated_step != counters.step:  # the final evaluation was cut
            # short: checkpoint and requeue; the resumed learner (at total_steps) evaluates and finishes
            outcome = self._check_control()
            assert outcome is not None
            return outcome
        if counters.step % self.config.log_every != 0:
            self._log()
        self._checkpoint()
        return self.control.finished()

    def _check_control(self) -> str | None:
        if self.control.interrupted:
            self._checkpoint()
            return self.control.requeue()
        if self.control.take_refusal():
            return self._stop_or_lost()
        if self.control.yield_to is not None:  # found at this step's checkpoint
            return self.control.yielded()
        return None

    def _stop_or_lost(self) -> str:
        if self.control.still_held_and_stopping():
            self._checkpoint()
            return self.control.stopped()
        return self.control.lost()

    # ================================================================== SAC
    def _sac_updates(self, count: int) -> None:
        """Alg. 2 lines 13-16, `count` times (the batches: `learner.updates`, on the host or the device)."""
        for _ in range(count):
            self.updates.sac_update()
            self.counters.total_updates += 1

    # ================================================================== reward classifier
    def _end_of_epoch_and_evaluation(self, *, epoch_end: bool, evaluation: bool) -> None:
        """The epoch's end and the evaluation due at this step. When both are, f_psi's steps run on the update
        thread (if there is one) while the evaluation's episodes run on the loop's thread; the evaluation is
        recorded after both, with the new f_psi, as when one follows the other."""
        training = self._end_of_epoch(beside_evaluation=evaluation) if epoch_end else None
        if evaluation:
            self._evaluate(training)

    def _end_of_epoch(self, *, beside_evaluation: bool = False) -> "Future[dict[str, float] | None] | None":
        """f_psi's epoch: at once or, when an evaluation follows and the update thread is there, on that thread (the
        future of its metrics)."""
        model, cfg, counters = self.reward_model, self.config, self.counters
        if model is None:
            return None
        if self.queries is not None:  # the observations waiting for a batch are scored by the f_psi of their time
            self.queries.score_pending()
        if self.spec.negatives == "pool" and len(model.initial_negatives) == 0:
            model.initial_negatives = self._first_epoch_negatives()
        if not self.spec.train_once:
            if beside_evaluation and self.classifier_beside_evaluation and cfg.classifier_steps:
                assert self.update_thread is not None
                return self.update_thread.submit(self._classifier_steps, cfg.classifier_steps, beside=True)
            self._train_classifier(cfg.classifier_steps)
            return None
        if counters.naive_trained:
            return None
        self.control.event(f"training the naive classifier once: {cfg.naive_classifier_steps} steps, then frozen")
        if self._train_classifier(cfg.naive_classifier_steps):
            counters.naive_trained = True
            self.control.event("naive classifier trained")
        else:  # not marked trained: the checkpoint says so, and the resumed learner trains it again
            self.control.event("naive classifier training interrupted; it is redone after the resume")
        return None

    def _first_epoch_negatives(self) -> np.ndarray:
        """Every observation of the first epoch (s and s' of its transitions), at most raq_initial_negatives."""
        frames = self.replay.frames_since(0)
        if len(frames) > self.config.raq_initial_negatives:
            keep = np.sort(self.rng.choice(len(frames), self.config.raq_initial_negatives, replace=False))
            frames = frames[keep]
        return frames.copy()

    def _train_classifier(self, steps: int) -> bool:
        """`steps` classifier steps (Alg. 2 lines 9-11), their metrics recorded; False when an interrupt cut them
        short."""
        metrics = self._classifier_steps(steps)
        if metrics is None:
            return False
        self._center_rewards(metrics)
        self._record_classifier_metrics(metrics)
        return True

    def _classifier_steps(self, steps: int, *, beside: bool = False) -> dict[str, float] | None:
        """`steps` classifier steps and the last one's metrics (its accuracies too: a second forward pass, once);
        None when an interrupt cut them short. `beside` (on the update thread, beside an evaluation): each step
        leaves the live f_psi as it was, for `_classifier_trained` to publish, and the loop's thread beats."""
        metrics: dict[str, float] = {}
        for i in range(steps):
            if self.control.interrupted:
                return None
            metrics = self.updates.classifier_step(accuracy=i == steps - 1, publish=not beside)
            if i % 50 == 49 and not beside:
                self.control.tick()
        return metrics

    def _classifier_trained(self, metrics: dict[str, float] | None) -> None:
        """After f_psi's steps on the update thread: the trained f_psi live, its metrics recorded (unless an
        interrupt cut the steps short)."""
        assert self.reward_model is not None
        self.reward_model.publish()
        if metrics is not None:
            self._center_rewards(metrics)
            self._record_classifier_metrics(metrics)

    def _center_rewards(self, metrics: dict[str, float]) -> None:
        """With `reward_centering`: the new f_psi's mean on uniform replay observations taken from its rewards."""
        if self.config.reward_centering and self.reward_model is not None:
            frames = self.replay.sample_next_frames(self.rng, 256)
            metrics["reward/offset"] = self.reward_model.center(frames)

    def _record_classifier_metrics(self, metrics: dict[str, float]) -> None:
        """An epoch's last classifier step's metrics with f_psi's view of the newest observations and of the
        answers; the query candidates rescored by the new f_psi."""
        model = self.reward_model
        if not metrics or model is None:
            return
        recent = self.replay.frames_since(self.replay.frames_added - 256)
        metrics["reward/mean_logit_recent"] = float(model.logits(recent).mean())
        metrics["reward/positives"] = float(len(model.goals) + len(model.answered_positives))
        if self.queries is not None:
            metrics.update(self.queries.agreement())
        self.store.record_metrics(run_id=self.run_id, step=self.counters.step, values=metrics)
        if self.queries is not None:
            self.queries.rescore()

    # ================================================================== evaluation and metrics
    def _loop_phase(self) -> str:
        return RunPhase.WARM_UP if self.counters.step < self.config.initial_random_steps else RunPhase.TRAINING

    def _evaluate(self, training: "Future[dict[str, float] | None] | None" = None) -> None:
        """Evaluate at this step. `training`: f_psi's steps running on the update thread meanwhile, finished before
        the evaluation is recorded (eval/classifier_return reads the new f_psi)."""
        step = self.counters.step
        self.control.set_phase(RunPhase.EVALUATING)
        try:
            episodes = self.evaluator.run_episodes(step)
        finally:
            if training is not None:
                self._classifier_trained(training.result())
            self.control.set_phase(self._loop_phase())
        if episodes is not None:
            self.evaluator.record(step, episodes)
            self.counters.evaluated_step = step
            if episodes:
                self._keep_evaluated_policy(step, episodes)
            elif self.actor is not None:  # real time: pi as it is at each evaluation step, to evaluate elsewhere
                save_checkpoint(sibling(self.checkpoint_file, POLICY_FILENAME), self._policy_state())

    def _keep_evaluated_policy(self, step: int, episodes: list[Any]) -> None:
        """The policy this evaluation ran (no update ran since its episodes), as policy-last-eval.pt, and as
        policy-best.pt when it scored best so far (success rate, then return), each with its step and score in the
        file and in policies.json: the export offers the policy whose score the run page showed."""
        if not self.control.holds_run():  # taken over meanwhile: the new holder keeps its own
            return
        successes = [episode.success for episode in episodes]
        score = {
            "step": step,
            "success_rate": float(np.mean(successes)) if all(s is not None for s in successes) else None,
            "return": float(np.mean([episode.total for episode in episodes])),
        }
        state = {**self._policy_state(), **score}
        index_location = sibling(self.checkpoint_file, POLICIES_INDEX)
        index = load_json(index_location) or {}
        save_checkpoint(sibling(self.checkpoint_file, LAST_EVAL_POLICY_FILENAME), state)
        index["last_eval"] = {"file": LAST_EVAL_POLICY_FILENAME, **score}

        def rank(entry: dict[str, Any]) -> tuple[float, float]:
            rate = entry.get("success_rate")
            return (-1.0 if rate is None else rate, entry.get("return") or 0.0)

        best = index.get("best")
        if best is None or rank(score) > rank(best):  # (an equal score keeps the earlier policy)
            save_checkpoint(sibling(self.checkpoint_file, BEST_POLICY_FILENAME), state)
            index["best"] = {"file": BEST_POLICY_FILENAME, **score}
        save_json(index_location, index)

    def _log(self) -> None:
        now, step, counters = time.monotonic(), self.counters.step, self.counters
        elapsed = max(now - self.log_time, 1e-9)
        steps_per_second = (step - self.log_step) / elapsed
        values = self.updates.take_metrics()
        for note in self.updates.take_notes():
            self.control.event(note, level="warning")
        if self.finished_returns:
            values["train/episode_return"] = float(np.mean(self.finished_returns))
            if all(s is not None for s in self.finished_successes):
                values["train/episode_success"] = float(np.mean(self.finished_successes))
        if self.queries is not None:
            values.update(self.queries.counts())
        if self.actor_periods:  # real time: the actor's control period, as it kept it
            periods = np.asarray(self.actor_periods) * 1000.0
            values["actor/period_ms_mean"] = float(periods.mean())
            values["actor/period_ms_p99"] = float(np.percentile(periods, 99))
            values["actor/period_ms_max"] = float(periods.max())
            self.actor_periods.clear()
        values["perf/steps_per_second"] = steps_per_second
        values["perf/updates_per_second"] = (counters.total_updates - self.log_updates) / elapsed
        remaining = self.config.total_steps - step
        training_since = getattr(self, "training_since", None)
        if training_since is not None and step - training_since[1] >= self.config.log_every:
            # the training phase's own speed so far (evaluations, classifier epochs and queries included)
            training_speed = (step - training_since[1]) / max(now - training_since[0], 1e-9)
            values["perf/training_steps_per_second"] = training_speed
            values["perf/eta_seconds"] = remaining / training_speed
        self.store.record_metrics(run_id=self.run_id, step=step, values=values)
        self.finished_returns.clear()
        self.finished_successes.clear()
        self.log_time, self.log_step, self.log_updates = now, step, counters.total_updates

    # ================================================================== checkpoints
    def _checkpoint(self) -> None:
        if not self.control.holds_run():  # taken over meanwhile: never overwrite the new holder's checkpoint
            self.control.beat_refused = True
            return
        if self.queries is not None:  # (a checkpoint keeps scored candidates, not the observations still waiting)
            self.queries.score_pending()
        started = time.monotonic()
        size = save_checkpoint(self.checkpoint_file, self._state())
        # the policy alone (actor, encoder, config: a few MB), for GET /api/runs/{id}/policy and learner.policy
        save_checkpoint(sibling(self.checkpoint_file, POLICY_FILENAME), self._policy_state())
        seconds = time.monotonic() - started
        self.control.event(f"checkpoint written at step {self.counters.step} ({size / 1e6:.1f} MB in {seconds:.1f} s)")
        self.control.tick()

    def _state(self) -> dict[str, Any]:
        return {
            "version": CHECKPOINT_VERSION,
            "config": json.dumps(self.config.to_dict()),
            **self.counters.state_dict(),
            "agent": self.agent.state_dict(),
            "reward_model": self.reward_model.state_dict() if self.reward_model is not None else None,
            "selector": self.queries.selector.state_dict() if self.queries is not None else None,
            "replay": self.replay.state_dict(),
            "rng": {
                "numpy": self.rng.bit_generator.state,
                "torch": torch.get_rng_state(),
                "acting": self.acting_generator.get_state(),
                "cuda": _cuda_rng_states(self.agent.device),
                "env": _env_rng_state(self.env),
                "envs": [_env_rng_state(episode.env) for episode in self.episodes],
            },
        }

    def _policy_state(self) -> dict[str, Any]:
        modules = {name: module.state_dict() for name, module in self.agent.modules().items() if name != "critic"}
        modules.pop("critic_target", None)
        return {"version": CHECKPOINT_VERSION, "config": json.dumps(self.config.to_dict()), "step": self.counters.step,
                "agent": modules}  # fmt: skip

    def _restore(self, state: dict[str, Any]) -> None:
        if state.get("version") != CHECKPOINT_VERSION:
            raise ValueError(f"checkpoint {self.checkpoint_file} has an unknown version {state.get('version')}")
        self.counters.load_state_dict(state)
        self.agent.load_state_dict(state["agent"])
        if self.reward_model is not None:
            self.reward_model.load_state_dict(state["reward_model"])
        if self.queries is not None:
            self.queries.selector.load_state_dict(state["selector"])
        self.replay.load_state_dict(state["replay"])
        self.rng.bit_generator.state = state["rng"]["numpy"]
        torch.set_rng_state(state["rng"]["torch"])
        # (checkpoints from before acting had a generator of its own: it starts afresh)
        if "acting" in state["rng"]:
            self.acting_generator.set_state(state["rng"]["acting"])
        cuda = state["rng"].get("cuda")
        # (another host may have another number of GPUs: then each keeps its own streams)
        if cuda is not None and torch.cuda.is_available() and len(cuda) == torch.cuda.device_count():
            torch.cuda.set_rng_state_all(cuda)
        # each env's generator continues its stream (checkpoints from before num_envs hold the first env's only)
        env_states = state["rng"].get("envs") or [state["rng"]["env"]]
        for index, (episode, env_state) in enumerate(zip(self.episodes, env_states, strict=False)):
            if env_state is not None:
                episode.env.reset(seed=env_seed(self.config.seed, index))  # creates the env's generator
                episode.env.unwrapped.np_random.bit_generator.state = env_state

    # ================================================================== goals
    def _load_goals(self) -> None:
        if self.reward_model is None:
            return
        if self.goal_set_id is None:
            raise ValueError(f"algorithm {self.config.algorithm!r} needs a goal set with goal examples")
        goals = self.store.goal_images(goal_set_id=self.goal_set_id)
        if not goals:
            raise ValueError(f"goal set {self.goal_set_id} has no goal examples")
        size = self.config.image_size
        images, remade = [], 0
        for goal in goals:
            image = decoded_array(goal.model_png)
            if image.shape[:2] != (size, size):  # the goal set's model size is not the run's: remake from original
                image = model_array(goal.original, size)
                remade += 1
            images.append(image)
        self.reward_model.goals = np.stack(images)
        note = f" ({remade} remade at {size}x{size} px from their originals)" if remade else ""
        self.control.event(f"loaded {len(goals)} goal examples{note}")


def uses_update_thread(config: TrainConfig, device: torch.device) -> bool:
    """`update_thread`: auto means on unless on a GPU, where the updates are asynchronous already (graph launches)."""
    return config.update_thread == "on" or (config.update_thread == "auto" and device.type != "cuda")


def env_seed(seed: int, index: int) -> int:
    """The first reset seed of training env `index`: the run's seed for the first, and for the others seeds drawn
    from (seed, index), so that runs with nearby seeds do not share env streams."""
    if index == 0:
        return seed
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


@dataclass
class EnvEpisode:
    """A training env and its current episode: the last observation, its replay slot, length and reward sum."""

    env: gymnasium.Env | ProcessEnv
    obs: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3), dtype=np.uint8))
    obs_slot: int = 0
    length: int = 0
    total: float = 0.0
    noise: EpisodeNoise | None = None
    """Its coloured exploration noise, drawn anew at each episode's start; None: i.i.d. (SAC's)."""


def _cuda_rng_states(device: torch.device) -> list[torch.Tensor] | None:
    if device.type == "cuda" and torch.cuda.is_available():
        return torch.cuda.get_rng_state_all()
    return None


def _env_rng_state(env: Any) -> dict[str, Any] | None:
    try:
        return env.unwrapped.np_random.bit_generator.state
    except AttributeError:
        return None
