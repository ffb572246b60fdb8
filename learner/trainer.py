"""What VICE-RAQ is, whatever executes it: one run's state and what happens at each env step (Alg. 2).

A runner (learner/lockstep.py, learner/real_time.py) steps the env and hands each step to `Trainer.record_step`,
then calls `after_step`, which does what is due at that step's interval: read answers, train f_psi (epoch ends),
evaluate, ask a query, record metrics, checkpoint, heartbeat. The SAC updates are the runner's to schedule
(`updates_due_by`), since when they run is how the loop executes.

Reward timing: the transition (s_t, a_t, s_{t+1}) is rewarded r = f_psi(s_{t+1}) (without a classifier, the env's
r_env(s_{t+1})), so the action that reaches the goal is the one credited; Alg. 2 writes r(s_t) but the state it
means is the outcome of the step. Episodes end on the time limit only (no terminal on success), so SAC bootstraps
through.
"""

import functools
import json
import time
from collections.abc import Callable
from concurrent.futures import Executor, Future
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import torch

from contract.algorithms import ALGORITHM_SPECS
from contract.checkpoint_location import (
    POLICY_FILENAME,
    sibling,
)
from contract.config import TrainConfig
from contract.envs import check_action_space, display_image, display_of_snapshot, model_image, snapshot_of, success_of
from contract.store import RunPhase, RunStatus, Store
from learner.checkpoint import load_checkpoint, save_checkpoint
from learner.env_steps import EnvEpisode, EnvStep, env_rng_state, env_seed
from learner.evaluation import Evaluator
from learner.networks import resolve_precision
from learner.policy_files import keep_evaluated_policy
from learner.queries import QueryChannel
from learner.replay import ReplayBuffer
from learner.reward import RewardModel, goal_examples
from learner.run_control import RunControl
from learner.sac import SACAgent
from learner.updates import make_updates

CHECKPOINT_VERSION = 1


class Trainer:
    """One run's VICE-RAQ: its networks, replay, f_psi, queries, evaluation, counters and checkpoint."""

    def __init__(
        self, config: TrainConfig, *, store: Store, control: RunControl, goal_set_id: int | None,
        checkpoint_file: Path | str, episodes: list[EnvEpisode], eval_envs: list[gymnasium.Env],
    ) -> None:  # fmt: skip
        """`episodes`: the training envs the runner steps; `eval_envs`: those evaluations run on (none: the run's
        policy is saved at each evaluation step, to be evaluated elsewhere)."""
        self.config, self.store, self.control, self.run_id = config, store, control, control.run_id
        self.goal_set_id, self.checkpoint_file = goal_set_id, checkpoint_file
        self.spec = ALGORITHM_SPECS[config.algorithm]
        self.counters = control.counters
        torch.manual_seed(config.seed)
        self.rng = np.random.default_rng(config.seed)
        self.episodes, self.eval_envs = episodes, eval_envs
        self.action_space = check_action_space(episodes[0].env)
        self.action_dim = int(self.action_space.shape[0])
        self.agent = SACAgent.for_run(config, self.action_dim)
        size = config.image_size
        self.replay = ReplayBuffer(config.replay_capacity, (size, size, 3), self.action_dim, envs=len(episodes))
        self.reward_model = RewardModel.for_run(config, self.rng) if self.spec.classifier else None
        self.queries: QueryChannel | None = None
        self.query_rule = config.queries
        if self.spec.queries and self.reward_model is not None:
            self.queries = QueryChannel(
                self.query_rule, store=store, run_id=self.run_id, reward_model=self.reward_model,
                counters=self.counters, control=control, keep_no_answers=keeps_no_answers(config),
                image_size=size,
            )  # fmt: skip
        self.updates = make_updates(
            config, agent=self.agent, replay=self.replay, reward_model=self.reward_model, spec=self.spec, rng=self.rng
        )  # fmt: skip
        self.evaluator = Evaluator(
            config.evaluation, config.task, envs=eval_envs, agent=self.agent, reward_model=self.reward_model,
            store=store, run_id=self.run_id, control=control,
        )  # fmt: skip
        # the policy's own generator: what acting draws (the lockstep runner's, or the actor's own) stays apart
        self.acting_generator = torch.Generator(device=self.agent.device).manual_seed(config.seed)
        self.classifier_thread: Executor | None = None
        """Where f_psi's epoch may train while an evaluation's episodes run (set by a runner that has one)."""
        self.metric_sources: list[Callable[[], dict[str, float]]] = [self.updates.take_metrics]
        self.after_checkpoint: list[Callable[[], None]] = []
        """What a runner does once a checkpoint is written."""
        self.finished_returns: list[float] = []
        self.finished_successes: list[float | None] = []
        self.log_time, self.log_step, self.log_updates = time.monotonic(), 0, 0
        self.training_since: tuple[float, int] | None = None

    # ================================================================== a step
    def record_step(self, step: EnvStep) -> bool:
        """One env step: its transition into the replay, the observation offered to the queries; True when it
        ended its episode (the runner begins the next)."""
        cfg, episode = self.config, step.episode
        raw, reward, terminated, truncated, info = step.outcome
        self.counters.step += 1
        episode.length += 1
        episode.total += float(reward)
        next_obs = model_image(raw, cfg.image_size, cfg.env_id)
        success, env_reward = success_of(info), self.spec.env_reward_of(info)
        if env_reward is None and self.spec.needs_env_reward:
            raise ValueError(
                f"algorithm {cfg.algorithm!r} needs the env to report info[{self.spec.env_reward!r}]; "
                f"{cfg.env_id} does not"
            )
        next_slot = self.replay.add_frame(next_obs)
        self.replay.add(episode.obs_slot, step.action, next_slot, bool(terminated), env_reward, person=step.person)
        self._observe(episode.env, next_obs, info, success)  # before any reset: the display render is of s_{t+1}
        if terminated or truncated or episode.length >= cfg.episode_steps:
            self.finished_returns.append(episode.total)
            self.finished_successes.append(success)
            return True
        episode.obs, episode.obs_slot = next_obs, next_slot
        return False

    def start_episode(self, episode: EnvEpisode, raw: Any, info: dict[str, Any]) -> None:
        """An episode begins at the observation `raw` of a reset."""
        episode.obs = model_image(raw, self.config.image_size, self.config.env_id)
        episode.obs_slot = self.replay.add_frame(episode.obs)
        episode.length, episode.total = 0, 0.0
        if episode.noise is not None:
            episode.noise.restart()
        self._observe(episode.env, episode.obs, info, success_of(info))

    def _observe(self, env: Any, image: np.ndarray, info: dict[str, Any], success: float | None) -> None:
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

    def steps_this_batch(self) -> int:
        """All envs, but no step past the next checkpoint (a higher-priority run may be waiting: the control
        check comes right after it) or the end of the run."""
        cfg, step = self.config, self.counters.step
        return min(len(self.episodes), cfg.total_steps - step, cfg.checkpoint_every - step % cfg.checkpoint_every)

    def updates_due_by(self, step: int) -> int:
        """SAC updates due in all by env step `step`: updates_per_step for each step from the warm-up's end on."""
        return max(0, step - self.config.initial_random_steps + 1) * self.config.updates_per_step

    def sac_updates(self, count: int) -> None:
        """Alg. 2 lines 13-16, `count` times (the batches: `learner.updates`, on the host or the device)."""
        for _ in range(count):
            self.updates.sac_update()
            self.counters.total_updates += 1

    def after_step(self) -> None:
        """What is due at this step's interval, in Alg. 2's order."""
        cfg, step = self.config, self.counters.step
        if self.queries is not None and (step % cfg.log_every == 0 or step % cfg.epoch_steps == 0):
            self.queries.read_answers()
        if step == cfg.initial_random_steps:
            self.control.event(f"warm-up done at step {step}: policy acting, SAC updates started")
            self.control.set_phase(RunPhase.TRAINING)
            self.training_since = (time.monotonic(), step)
        epoch_end, evaluation = step % cfg.epoch_steps == 0, step % cfg.eval_every == 0
        training = self._end_of_epoch(beside_evaluation=evaluation) if epoch_end else None
        if evaluation:
            self._evaluate(training)
        if self.queries is not None and self.query_rule.asks_after(step, asked=self.queries.asked):
            self.queries.ask()
        if step % cfg.log_every == 0:
            self._log()
        if step % cfg.checkpoint_every == 0 and step < cfg.total_steps and not self.control.interrupted:
            self.checkpoint()  # (interrupted: the loop checkpoints at once)
            self.control.look_for_higher_priority()
        self.control.tick()

    # ================================================================== start and end
    def set_up(self) -> bool | None:
        """Goals, checkpoint, asked queries; True when resumed from a checkpoint, None when the run is no longer
        this learner's to train."""
        cfg, control = self.config, self.control
        precision = resolve_precision(cfg.precision, self.agent.device.type)
        auto = " (auto: the faster on this machine)" if cfg.precision == "auto" else ""
        control.event(
            f"learner {control.worker} setting up: {cfg.algorithm} on {cfg.env_id}, {cfg.total_steps} steps, "
            f"precision {precision}{auto}; {self.updates.describe()}"
        )
        stored_step = int(self.store.get_run(run_id=self.run_id).step or 0)
        # each setup phase can take long (a large checkpoint): beat after each so no one reclaims the run
        self.load_goals()
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
        if state is not None:
            dropped = self.store.delete_metrics_after(run_id=self.run_id, step=self.counters.step)
            control.event(f"resumed from checkpoint at step {self.counters.step}; {dropped} metrics recorded after it "
                          "were dropped")  # fmt: skip
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

    def begin_training(self, *, resumed: bool) -> None:
        """After a resume, what an interrupt cut short before the checkpoint (the naive classifier's one-off
        training, the evaluation of the checkpoint's step); then the phase, and the speed measured from here."""
        cfg, counters = self.config, self.counters
        if resumed and self.spec.train_once and not counters.naive_trained and counters.step >= cfg.epoch_steps:
            self._end_of_epoch()
        step = counters.step
        if resumed and 0 < step < cfg.total_steps and step % cfg.eval_every == 0 and counters.evaluated_step != step:
            self._evaluate()
        self.control.set_phase(self._loop_phase())
        self.log_time, self.log_step, self.log_updates = time.monotonic(), step, counters.total_updates
        # the ETA is taken from the training phase's speed only (the random warm-up runs several times faster)
        self.training_since = (self.log_time, step) if step >= cfg.initial_random_steps else None

    def check_control(self) -> str | None:
        """How training ends now (an interrupt, a refused heartbeat, a higher-priority run), or None."""
        if self.control.interrupted:
            self.checkpoint()
            return self.control.requeue()
        if self.control.take_refusal():
            return self.stop_or_lost()
        if self.control.yield_to is not None:  # found at this step's checkpoint
            return self.control.yielded()
        return None

    def stop_or_lost(self) -> str:
        if self.control.still_held_and_stopping():
            self.checkpoint()
            return self.control.stopped()
        return self.control.lost()

    def finish(self) -> str:
        counters = self.counters
        if counters.evaluated_step != counters.step:
            self._evaluate()
        if self.control.interrupted and counters.evaluated_step != counters.step:  # the final evaluation was cut
            # short: checkpoint and requeue; the resumed learner (at total_steps) evaluates and finishes
            outcome = self.check_control()
            assert outcome is not None
            return outcome
        if counters.step % self.config.log_every != 0:
            self._log()
        self.checkpoint()
        return self.control.finished()

    # ================================================================== the reward classifier
    def _end_of_epoch(self, *, beside_evaluation: bool = False) -> "Future[dict[str, float] | None] | None":
        """f_psi's epoch (Alg. 2 lines 9-11): at once or, when an evaluation follows and the runner gave a thread
        for it, on that thread (the future of its metrics, recorded after the evaluation's episodes)."""
        model, cfg, counters = self.reward_model, self.config, self.counters
        if model is None:
            return None
        if self.queries is not None:  # the observations waiting for a batch are scored by the f_psi of their time
            self.queries.score_pending()
        if self.spec.negatives == "pool" and len(model.initial_negatives) == 0:
            model.initial_negatives = self._first_epoch_negatives()
        if not self.spec.train_once:
            if beside_evaluation and self.classifier_thread is not None and cfg.classifier_steps:
                return self.classifier_thread.submit(self._classifier_steps, cfg.classifier_steps, beside=True)
            self._record_classifier_metrics(self._classifier_steps(cfg.classifier_steps))
            return None
        if counters.naive_trained:
            return None
        self.control.event(f"training the naive classifier once: {cfg.naive_classifier_steps} steps, then frozen")
        metrics = self._classifier_steps(cfg.naive_classifier_steps)
        if metrics is None:  # not marked trained: the checkpoint says so, and the resumed learner trains it again
            self.control.event("naive classifier training interrupted; it is redone after the resume")
            return None
        counters.naive_trained = True
        self.control.event("naive classifier trained")
        self._record_classifier_metrics(metrics)
        return None

    def _first_epoch_negatives(self) -> np.ndarray:
        """Every observation of the first epoch (s and s' of its transitions), at most raq_initial_negatives."""
        frames = self.replay.frames_since(0)
        if len(frames) > self.config.raq_initial_negatives:
            keep = np.sort(self.rng.choice(len(frames), self.config.raq_initial_negatives, replace=False))
            frames = frames[keep]
        return frames.copy()

    def _classifier_steps(self, steps: int, *, beside: bool = False) -> dict[str, float] | None:
        """`steps` classifier steps and the last one's metrics (its accuracies too: a second forward pass, once);
        None when an interrupt cut them short. `beside` (on another thread, beside an evaluation): each step
        leaves the live f_psi as it was, published once the evaluation's episodes are done."""
        metrics: dict[str, float] = {}
        for i in range(steps):
            if self.control.interrupted:
                return None
            metrics = self.updates.classifier_step(accuracy=i == steps - 1, publish=not beside)
            if i % 50 == 49 and not beside:
                self.control.tick()
        return metrics

    def _record_classifier_metrics(self, metrics: dict[str, float] | None) -> None:
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

    def load_goals(self) -> None:
        """The goal set's examples as f_psi's positives, at the run's image size."""
        if self.reward_model is not None:
            if self.goal_set_id is None:
                raise ValueError(f"algorithm {self.config.algorithm!r} needs a goal set with goal examples")
            self.reward_model.goals, note = goal_examples(self.store, self.goal_set_id, self.config.image_size)
            self.control.event(note)

    # ================================================================== evaluation and metrics
    def _loop_phase(self) -> str:
        return RunPhase.WARM_UP if self.counters.step < self.config.initial_random_steps else RunPhase.TRAINING

    def _evaluate(self, training: "Future[dict[str, float] | None] | None" = None) -> None:
        """Evaluate at this step. `training`: f_psi's steps running on another thread meanwhile, finished before
        the evaluation is recorded (eval/classifier_return reads the new f_psi)."""
        step = self.counters.step
        self.control.set_phase(RunPhase.EVALUATING)
        try:
            episodes = self.evaluator.run_episodes(step)
        finally:
            if training is not None:
                metrics = training.result()
                assert self.reward_model is not None
                self.reward_model.publish()
                self._record_classifier_metrics(metrics)
            self.control.set_phase(self._loop_phase())
        if episodes is None:
            return
        self.evaluator.record(step, episodes)
        self.counters.evaluated_step = step
        if not episodes:  # no evaluation envs: pi as it is at each evaluation step, to evaluate elsewhere
            save_checkpoint(sibling(self.checkpoint_file, POLICY_FILENAME), self.policy_state())
        elif self.control.holds_run():  # (taken over meanwhile: the new holder keeps its own)
            keep_evaluated_policy(self.checkpoint_file, self.policy_state(), step, episodes)

    def _log(self) -> None:
        """The training metrics since the last record: speed, episodes, queries, updates, the runner's own."""
        now, step, counters = time.monotonic(), self.counters.step, self.counters
        elapsed = max(now - self.log_time, 1e-9)
        values: dict[str, float] = {}
        for source in self.metric_sources:
            values.update(source())
        for note in self.updates.take_notes():
            self.control.event(note, level="warning")
        if self.finished_returns:
            values["train/episode_return"] = float(np.mean(self.finished_returns))
            if all(s is not None for s in self.finished_successes):
                values["train/episode_success"] = float(np.mean(self.finished_successes))
        if self.queries is not None:
            values.update(self.queries.counts())
        values["perf/steps_per_second"] = (step - self.log_step) / elapsed
        values["perf/updates_per_second"] = (counters.total_updates - self.log_updates) / elapsed
        if self.training_since is not None and step - self.training_since[1] >= self.config.log_every:
            # the training phase's own speed so far (evaluations, classifier epochs and queries included)
            training_speed = (step - self.training_since[1]) / max(now - self.training_since[0], 1e-9)
            values["perf/training_steps_per_second"] = training_speed
            values["perf/eta_seconds"] = (self.config.total_steps - step) / training_speed
        self.store.record_metrics(run_id=self.run_id, step=step, values=values)
        self.finished_returns.clear()
        self.finished_successes.clear()
        self.log_time, self.log_step, self.log_updates = now, step, counters.total_updates

    # ================================================================== checkpoints
    def checkpoint(self) -> None:
        if not self.control.holds_run():  # taken over meanwhile: never overwrite the new holder's checkpoint
            self.control.beat_refused = True
            return
        if self.queries is not None:  # (a checkpoint keeps scored candidates, not the observations still waiting)
            self.queries.score_pending()
        started = time.monotonic()
        size = save_checkpoint(self.checkpoint_file, self._state())
        # the policy alone (actor, encoder, config: a few MB), for GET /api/runs/{id}/policy and learner.policy
        save_checkpoint(sibling(self.checkpoint_file, POLICY_FILENAME), self.policy_state())
        seconds = time.monotonic() - started
        self.control.event(f"checkpoint written at step {self.counters.step} ({size / 1e6:.1f} MB in {seconds:.1f} s)")
        for written in self.after_checkpoint:
            written()
        self.control.tick()

    def _state(self) -> dict[str, Any]:
        envs = [env_rng_state(episode.env) for episode in self.episodes]
        return {
            "version": CHECKPOINT_VERSION,
            "config": json.dumps(self.config.to_dict()),
            **self.counters.state_dict(),
            "agent": self.agent.state_dict(),
            "reward_model": self.reward_model.state_dict() if self.reward_model is not None else None,
            "selector": self.queries.selector.state_dict() if self.queries is not None else None,
            "replay": self.replay.state_dict(),
            "episodes": [episode.state_dict() for episode in self.episodes],
            "rng": {
                "numpy": self.rng.bit_generator.state, "torch": torch.get_rng_state(),
                "acting": self.acting_generator.get_state(), "cuda": _cuda_rng_states(self.agent.device),
                "env": envs[0], "envs": envs,
            },
        }  # fmt: skip

    def policy_state(self) -> dict[str, Any]:
        """The policy's modules (actor and encoder, not the critics) with the config and step."""
        modules = {name: module.state_dict() for name, module in self.agent.modules().items()
                   if name not in ("critic", "critic_target")}  # fmt: skip
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
        for episode, saved in zip(self.episodes, state.get("episodes") or [], strict=False):
            episode.load_state_dict(saved, self.replay.frames)
        rng = state["rng"]
        self.rng.bit_generator.state = rng["numpy"]
        torch.set_rng_state(rng["torch"])
        if "acting" in rng:  # (checkpoints from before acting had a generator of its own: it starts afresh)
            self.acting_generator.set_state(rng["acting"])
        # (another host may have another number of GPUs: then each keeps its own streams)
        if rng.get("cuda") is not None and torch.cuda.is_available() and len(rng["cuda"]) == torch.cuda.device_count():
            torch.cuda.set_rng_state_all(rng["cuda"])
        # each env's generator continues its stream (checkpoints from before num_envs hold the first env's only)
        for index, (episode, env_state) in enumerate(zip(self.episodes, rng.get("envs") or [rng["env"]], strict=False)):
            if env_state is not None:
                episode.env.reset(seed=env_seed(self.config.seed, index))  # creates the env's generator
                episode.env.unwrapped.np_random.bit_generator.state = env_state


def keeps_no_answers(config: TrainConfig) -> bool:
    """A "no" joins f_psi's negatives: raq's pool, or VICE-RAQ's answered negatives when it samples from them."""
    return ALGORITHM_SPECS[config.algorithm].negatives == "pool" or config.no_answer_share > 0


def _cuda_rng_states(device: torch.device) -> list[torch.Tensor] | None:
    if device.type == "cuda" and torch.cuda.is_available():
        return torch.cuda.get_rng_state_all()
    return None
