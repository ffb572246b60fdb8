"""The training loop of one run: SAC from pixels with the run's reward method, reading and writing only the Store.

Per environment step t -> t+1 (Alg. 2): act (uniformly at random for the first initial_random_steps), store
(s_t, a_t, s_{t+1}), score s_{t+1} as a query candidate; then, at their intervals: read answers, train f_psi
(epoch ends), ask a query, do updates_per_step SAC updates, evaluate, record metrics, checkpoint, heartbeat.

Reward timing: the transition (s_t, a_t, s_{t+1}) is rewarded r = f_psi(s_{t+1}) (sparse: success(s_{t+1})),
so the action that reaches the goal is the one credited; Alg. 2 writes r(s_t) but the state it means is the
outcome of the step. Episodes end on the time limit only (no terminal on success), so SAC bootstraps through.
"""

import contextlib
import io
import json
import logging
import threading
import time
from collections import defaultdict
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image, ImageOps

from app.store import QueryStatus, Run, RunStatus, Store
from learner.checkpoint import checkpoint_path, load_checkpoint, save_checkpoint
from learner.config import TrainConfig
from learner.envs import (
    check_action_space,
    decode_image,
    display_image,
    encode_gif,
    encode_png,
    jsonable,
    make_env,
    model_image,
    scale_action,
    success_of,
)
from learner.networks import resolve_precision
from learner.queries import QuerySelector, digest
from learner.replay import ReplayBuffer, shift_pad
from learner.reward import AIRL_ALGORITHMS, CLASSIFIER_ALGORITHMS, RewardModel
from learner.sac import SACAgent

logger = logging.getLogger(__name__)
QUERY_ALGORITHMS = ("vice_raq", "raq")
POOL_ALGORITHMS = ("raq", "naive_classifier")
CHECKPOINT_VERSION = 1


class Outcome:
    FINISHED = "finished"
    STOPPED = "stopped"
    REQUEUED = "requeued"
    LOST = "lost"


def config_for_run(run: Run) -> TrainConfig:
    """The run's stored config; its own columns (env, algorithm, seed, total steps) win over the JSON."""
    config = TrainConfig.from_dict(dict(run.config or {}))
    total = int(run.total_steps) if run.total_steps else config.total_steps
    return replace(config, env_id=run.env_id, algorithm=run.algorithm, seed=run.seed, total_steps=total)


def train_run(
    store: Store, run: Run, *, checkpoint_dir: Path, worker: str, interrupt: threading.Event | None = None
) -> str:
    """Train a claimed run to its end, a stop, an interrupt (re-queued) or its loss to another worker."""
    trainer = Trainer(
        config_for_run(run), store=store, run_id=run.id, worker=worker, goal_set_id=run.goal_set_id,
        checkpoint_file=checkpoint_path(checkpoint_dir, run.id), interrupt=interrupt,
    )  # fmt: skip
    try:
        return trainer.train()
    finally:
        trainer.close()


class Trainer:
    """One run's state and loop. Public: train() -> Outcome; close()."""

    def __init__(
        self, config: TrainConfig, *, store: Store, run_id: int, worker: str, goal_set_id: int | None,
        checkpoint_file: Path, interrupt: threading.Event | None = None,
    ) -> None:  # fmt: skip
        self.config, self.store, self.run_id, self.worker = config, store, run_id, worker
        self.goal_set_id, self.checkpoint_file = goal_set_id, checkpoint_file
        self.interrupt = interrupt or threading.Event()
        torch.manual_seed(config.seed)
        self.rng = np.random.default_rng(config.seed)
        size = config.image_size
        self.env = make_env(config.env_id, image_size=size, display_size=config.display_size)
        self.eval_env = make_env(config.env_id, image_size=size, display_size=config.display_size)
        self.action_space = check_action_space(self.env)
        self.action_dim = int(self.action_space.shape[0])
        self.agent = SACAgent(config, self.action_dim)
        self.replay = ReplayBuffer(config.replay_capacity, (size, size, 3), self.action_dim)
        self.reward_model = RewardModel(config, self.rng) if config.algorithm in CLASSIFIER_ALGORITHMS else None
        queries = config.algorithm in QUERY_ALGORITHMS
        self.selector = QuerySelector(config.query_strategy, config.query_candidates) if queries else None
        self.pad = shift_pad(size) if config.augmentation == "random_shift" else 0
        self.step = 0
        self.total_updates = 0
        self.answer_cursor = 0
        self.queries_asked = 0
        # every answered query's image and answer, by query id: what the page shows as the classifier's
        # agreement with the person (rebuilt from the store on resume)
        self.answered: dict[int, tuple[np.ndarray, bool]] = {}
        self.naive_trained = False
        self.evaluated_step = -1  # the step of the last completed evaluation
        self.step_known = False  # until the checkpoint is read, heartbeats leave the run's stored step alone
        self.obs = np.zeros((size, size, 3), dtype=np.uint8)
        self.obs_slot = 0
        self.episode_len = 0
        self.episode_return = 0.0
        self.finished_returns: list[float] = []
        self.finished_successes: list[float | None] = []
        self.update_sums: dict[str, float] = defaultdict(float)
        self.update_count = 0
        self.last_beat = 0.0
        self.beat_failed = False
        self.log_time, self.log_step, self.log_updates = time.monotonic(), 0, 0

    # ================================================================== the loop
    def train(self) -> str:
        cfg = self.config
        precision = resolve_precision(cfg.precision, self.agent.device.type)
        self._event(
            f"learner {self.worker} setting up: {cfg.algorithm} on {cfg.env_id}, {cfg.total_steps} steps, "
            f"precision {precision}" + (" (auto: the faster on this machine)" if cfg.precision == "auto" else "")
        )
        stored_step = int(self.store.get_run(run_id=self.run_id).step or 0)
        # each setup phase can take long (a large checkpoint): beat after each so no one reclaims the run
        self._load_goals()
        self._tick()
        state = load_checkpoint(self.checkpoint_file)
        self._tick()
        if state is not None:
            self._restore(state)
        self.step_known = True
        self._tick()
        self._sync_queries()
        if not self._beat(status=RunStatus.TRAINING):
            return self._stop_or_lost()
        if state is not None:
            dropped = self.store.delete_metrics_after(run_id=self.run_id, step=self.step)
            self._event(
                f"resumed from checkpoint at step {self.step}; {dropped} metrics recorded after it were dropped"
            )
        else:
            if stored_step > 0:
                dropped = self.store.delete_metrics_after(run_id=self.run_id, step=0)
                self._event(
                    f"the run had reached step {stored_step} but no checkpoint was found at {self.checkpoint_file}: "
                    f"training restarts from step 0 ({dropped} earlier metrics dropped). Checkpoints must be on a "
                    "data dir shared by all learners, or a run that moves to another host starts over.",
                    level="warning",
                )
            if cfg.initial_random_steps:
                self._event(f"warm-up started: {cfg.initial_random_steps} uniformly random steps")
        self._begin_episode(seed=None if state is not None else cfg.seed)
        if state is not None:
            self._redo_interrupted_work()
        self.log_time, self.log_step, self.log_updates = time.monotonic(), self.step, self.total_updates
        while self.step < cfg.total_steps:
            outcome = self._check_control()
            if outcome is not None:
                return outcome
            self._env_step()
            self._after_step()
        return self._finish()

    def _redo_interrupted_work(self) -> None:
        """After a resume: what an interrupt cut short before the checkpoint (the naive classifier's one-off
        training, the evaluation of the checkpoint's step) is done now."""
        cfg = self.config
        if cfg.algorithm == "naive_classifier" and not self.naive_trained and self.step >= cfg.epoch_steps:
            self._end_of_epoch()
        if 0 < self.step < cfg.total_steps and self.step % cfg.eval_every == 0 and self.evaluated_step != self.step:
            self._evaluate()

    def close(self) -> None:
        for env in (self.env, self.eval_env):
            with contextlib.suppress(Exception):  # closing must not hide the error that ended training
                env.close()

    def _env_step(self) -> None:
        cfg = self.config
        if self.step < cfg.initial_random_steps:
            action = self.rng.uniform(-1.0, 1.0, self.action_dim).astype(np.float32)
        else:
            action = self.agent.act(self.obs)
        raw, reward, terminated, truncated, info = self.env.step(scale_action(action, self.action_space))
        self.step += 1
        self.episode_len += 1
        self.episode_return += float(reward)
        next_obs = model_image(raw, cfg.image_size)
        success = success_of(info)
        if success is None and cfg.algorithm == "sparse":
            raise ValueError(f"algorithm 'sparse' needs the env to report info['success']; {cfg.env_id} does not")
        next_slot = self.replay.add_frame(next_obs)
        self.replay.add(self.obs_slot, action, next_slot, bool(terminated), success)
        self._observe(next_obs, info, success)  # before any reset: the display render is of s_{t+1}
        if terminated or truncated or self.episode_len >= cfg.episode_steps:
            self.finished_returns.append(self.episode_return)
            self.finished_successes.append(success)
            self._begin_episode()
        else:
            self.obs, self.obs_slot = next_obs, next_slot

    def _begin_episode(self, seed: int | None = None) -> None:
        raw, info = self.env.reset(seed=seed)
        self.obs = model_image(raw, self.config.image_size)
        self.obs_slot = self.replay.add_frame(self.obs)
        self.episode_len, self.episode_return = 0, 0.0
        self._observe(self.obs, info, success_of(info))

    def _after_step(self) -> None:
        cfg, step = self.config, self.step
        if step % cfg.log_every == 0 or step % cfg.epoch_steps == 0:
            self._read_answers()
        if step % cfg.epoch_steps == 0:
            self._end_of_epoch()
        if self.selector is not None and step % cfg.query_every == 0:
            self._query()
        if step == cfg.initial_random_steps:
            self._event(f"warm-up done at step {step}: policy acting, SAC updates started")
        if step >= cfg.initial_random_steps:
            self._sac_updates()
        if step % cfg.eval_every == 0:
            self._evaluate()
        if step % cfg.log_every == 0:
            self._log()
        if step % cfg.checkpoint_every == 0 and step < cfg.total_steps and not self.interrupt.is_set():
            self._checkpoint()  # (interrupted: the loop checkpoints at once)
        self._tick()

    def _finish(self) -> str:
        if self.evaluated_step != self.step:
            self._evaluate()
        if self.interrupt.is_set() and self.evaluated_step != self.step:  # the final evaluation was cut short:
            # checkpoint and requeue; the resumed learner (at total_steps) evaluates and finishes
            outcome = self._check_control()
            assert outcome is not None
            return outcome
        if self.step % self.config.log_every != 0:
            self._log()
        self._checkpoint()
        self._beat()
        self.store.set_run_status(run_id=self.run_id, status=RunStatus.FINISHED, worker=self.worker)
        return Outcome.FINISHED

    # ================================================================== SAC
    def _sac_updates(self) -> None:
        for _ in range(self.config.updates_per_step):
            batch = self.replay.sample(self.rng, self.config.batch_size, self.pad)
            rewards = self._rewards(batch.indices)
            metrics = self.agent.update_from_arrays(batch.obs, batch.action, rewards, batch.next_obs, batch.not_done)
            metrics["reward/batch_mean"] = float(rewards.mean())
            for name, value in metrics.items():
                self.update_sums[name] += value
            self.update_count += 1
            self.total_updates += 1

    def _rewards(self, indices: np.ndarray) -> np.ndarray:
        """Alg. 2 line 15, with the current classifier: r = f_psi(s'); sparse: the env's success(s')."""
        if self.reward_model is None:
            return self.replay.success[indices].astype(np.float32)
        return self.reward_model.rewards(self.replay, indices)

    # ================================================================== reward classifier
    def _end_of_epoch(self) -> None:
        model, cfg = self.reward_model, self.config
        if model is None:
            return
        if cfg.algorithm in POOL_ALGORITHMS and len(model.initial_negatives) == 0:
            model.initial_negatives = self._first_epoch_negatives()
        if cfg.algorithm == "naive_classifier":
            if self.naive_trained:
                return
            self._event(f"training the naive classifier once: {cfg.naive_classifier_steps} steps, then frozen")
            if self._train_classifier(cfg.naive_classifier_steps):
                self.naive_trained = True
                self._event("naive classifier trained")
            else:  # not marked trained: the checkpoint says so, and the resumed learner trains it again
                self._event("naive classifier training interrupted; it is redone after the resume")
            return
        self._train_classifier(cfg.classifier_steps)

    def _first_epoch_negatives(self) -> np.ndarray:
        """Every observation of the first epoch (s and s' of its transitions), at most raq_initial_negatives."""
        frames = self.replay.frames_since(0)
        if len(frames) > self.config.raq_initial_negatives:
            keep = np.sort(self.rng.choice(len(frames), self.config.raq_initial_negatives, replace=False))
            frames = frames[keep]
        return frames.copy()

    def _train_classifier(self, steps: int) -> bool:
        """`steps` classifier steps; False when an interrupt (Ctrl-C, SIGTERM) cut them short."""
        model, cfg = self.reward_model, self.config
        assert model is not None
        policy = self.agent.policy if cfg.algorithm in AIRL_ALGORITHMS else None
        metrics: dict[str, float] = {}
        for i in range(steps):
            if self.interrupt.is_set():
                return False
            positives = model.sample_positives(cfg.classifier_batch_size)
            if cfg.algorithm in AIRL_ALGORITHMS:  # negatives: uniform replay samples
                negatives = self.replay.sample_next_frames(self.rng, cfg.classifier_batch_size)
            else:
                negatives = model.sample_negatives(cfg.classifier_batch_size)
            # the accuracies (a second forward pass) only for the step whose metrics are recorded
            metrics = model.update_classifier(positives, negatives, policy, accuracy=i == steps - 1)
            if i % 50 == 49:
                self._tick()
        if not metrics:
            return True
        recent = self.replay.frames_since(self.replay.frames_added - 256)
        metrics["reward/mean_logit_recent"] = float(model.logits(recent).mean())
        metrics["reward/positives"] = float(len(model.goals) + len(model.answered_positives))
        metrics.update(self._agreement_with_answers())
        self.store.record_metrics(run_id=self.run_id, step=self.step, values=metrics)
        if self.selector is not None:
            self.selector.rescore(model.logits)
        return True

    def _agreement_with_answers(self) -> dict[str, float]:
        """What f_psi now says about the answered queries (exploitation shows as high f_psi on 'no' answers):
        mean f_psi on yes and on no answers, and the fraction on the answer's side of f_psi = 0."""
        if not self.answered or self.reward_model is None:
            return {}
        images = np.stack([image for image, _ in self.answered.values()])
        labels = np.array([answer for _, answer in self.answered.values()])
        logits = self.reward_model.logits(images)
        metrics = {"reward/agreement_with_answers": float(np.mean((logits > 0) == labels))}
        if labels.any():
            metrics["reward/mean_logit_answered_yes"] = float(logits[labels].mean())
        if not labels.all():
            metrics["reward/mean_logit_answered_no"] = float(logits[~labels].mean())
        return metrics

    # ================================================================== queries and answers
    def _observe(self, image: np.ndarray, info: dict[str, Any], success: float | None) -> None:
        """Score a new observation as a query candidate; its display render is taken now, of this same state."""
        if self.selector is None or self.queries_asked >= self.config.query_budget:
            return
        assert self.reward_model is not None
        score = float(self.reward_model.logits(image[None])[0])
        self.selector.offer(
            score, image, lambda: display_image(self.env, self.config.display_size, image),
            env_step=self.step, info=jsonable(info), success=success,
        )  # fmt: skip

    def _query(self) -> None:
        assert self.selector is not None and self.reward_model is not None
        if self.queries_asked >= self.config.query_budget:
            return
        self.selector.rescore(self.reward_model.logits)
        candidate = self.selector.select()
        if candidate is None:
            return
        query = self.store.post_query(
            run_id=self.run_id, env_step=candidate.env_step, model_png=encode_png(candidate.image),
            display_png=encode_png(candidate.display), score=candidate.score, strategy=self.config.query_strategy,
            info=candidate.info, ground_truth_success=candidate.success,
        )  # fmt: skip
        self.queries_asked += 1
        probability = 1.0 / (1.0 + np.exp(-np.clip(candidate.score, -50, 50)))
        self._event(
            f"query {query.id} posted ({self.queries_asked}/{self.config.query_budget}): observation of step "
            f"{candidate.env_step}, f_psi {candidate.score:.3f} (p = {probability:.3f})"
        )
        if self.queries_asked >= self.config.query_budget:
            self._event("query budget spent: no more queries")

    def _read_answers(self) -> None:
        """New answers: a yes joins the positives; raq also takes a no as a negative (vice_raq needs not)."""
        model = self.reward_model
        if self.selector is None or model is None:
            return
        answers = self.store.new_answers(run_id=self.run_id, since_seq=self.answer_cursor)
        yes = no = 0
        for answer in answers:
            image = decode_image(answer.model_png, self.config.image_size)
            self.answered[answer.query_id] = (image, answer.success)
            if answer.success:
                model.add_positive(image)
                yes += 1
            else:
                no += 1
                if self.config.algorithm == "raq":
                    model.add_negative(image)
            self.answer_cursor = max(self.answer_cursor, answer.answer_seq)
        if answers:
            self._event(
                f"answers received: {yes} yes, {no} no; the classifier now has "
                f"{len(model.goals) + len(model.answered_positives)} positives"
            )

    def _sync_queries(self) -> None:
        """Queries this run already asked (also after the last checkpoint) count against the budget and are
        never asked again."""
        if self.selector is None:
            return
        queries = self.store.list_queries(run_id=self.run_id, limit=1_000_000)
        self.queries_asked = len(queries)
        size = self.config.image_size
        keys = set()
        for query in queries:
            self._tick()
            image = decode_image(self.store.query_image(query_id=query.id, resolution="model"), size)
            keys.add(digest(image))
            if query.status == QueryStatus.ANSWERED and query.used_at is not None:
                self.answered[query.id] = (image, bool(query.answer))
        self.selector.mark_asked(keys)

    # ================================================================== evaluation and metrics
    def _evaluate(self) -> None:
        """eval_episodes deterministic episodes. eval/return is the env's own reward summed; with a classifier,
        eval/classifier_return sums f_psi(s'); eval/success_rate: success of each episode's final state.
        An interrupt stops it without recording anything."""
        cfg = self.config
        if cfg.eval_episodes == 0:
            self.evaluated_step = self.step
            return
        returns, classifier_returns, successes, frames = [], [], [], []
        for episode in range(cfg.eval_episodes):
            total, next_frames, success, episode_frames = self._eval_episode(episode, record=episode == 0)
            if self.interrupt.is_set():
                return
            returns.append(total)
            successes.append(success)
            frames = frames or episode_frames
            if self.reward_model is not None:
                classifier_returns.append(float(self.reward_model.logits(np.stack(next_frames)).sum()))
            self._tick()
        values = {"eval/return": float(np.mean(returns))}
        if classifier_returns:
            values["eval/classifier_return"] = float(np.mean(classifier_returns))
        known = [s for s in successes if s is not None]
        if len(known) == len(successes):
            values["eval/success_rate"] = float(np.mean(known))
        self.store.record_metrics(run_id=self.run_id, step=self.step, values=values)
        self.store.record_rollout(
            run_id=self.run_id, env_step=self.step, data=encode_gif(frames), frame_count=len(frames),
            media_type="image/gif", episode_return=returns[0], success=successes[0],
        )  # fmt: skip
        rate = f", success rate {values['eval/success_rate']:.2f}" if "eval/success_rate" in values else ""
        self._event(f"evaluation at step {self.step}: return {values['eval/return']:.2f}{rate}")
        self.evaluated_step = self.step

    def _eval_episode(self, episode: int, record: bool) -> tuple[float, list[np.ndarray], float | None, list]:
        cfg = self.config
        raw, info = self.eval_env.reset(seed=cfg.seed * 100_003 + 1_000_000 + self.step + episode)
        obs = model_image(raw, cfg.image_size)
        frames = [display_image(self.eval_env, cfg.rollout_size, obs)] if record else []
        total, next_frames, success = 0.0, [], success_of(info)
        for _ in range(cfg.episode_steps):
            if self.interrupt.is_set():
                break
            action = self.agent.act(obs, deterministic=True)
            raw, reward, terminated, truncated, info = self.eval_env.step(scale_action(action, self.action_space))
            obs = model_image(raw, cfg.image_size)
            total += float(reward)
            next_frames.append(obs)
            success = success_of(info)
            if record:
                frames.append(display_image(self.eval_env, cfg.rollout_size, obs))
            if terminated or truncated:
                break
        return total, next_frames, success, frames

    def _log(self) -> None:
        now = time.monotonic()
        elapsed = max(now - self.log_time, 1e-9)
        steps_per_second = (self.step - self.log_step) / elapsed
        count = max(self.update_count, 1)
        values = {name: total / count for name, total in self.update_sums.items()}
        if self.finished_returns:
            values["train/episode_return"] = float(np.mean(self.finished_returns))
            if all(s is not None for s in self.finished_successes):
                values["train/episode_success"] = float(np.mean(self.finished_successes))
        if self.selector is not None:
            counts = self.store.query_counts(run_id=self.run_id)
            for name in ("asked", "answered", "yes", "pending"):
                values[f"queries/{name}"] = float(counts.get(name, 0))
        values["perf/steps_per_second"] = steps_per_second
        values["perf/updates_per_second"] = (self.total_updates - self.log_updates) / elapsed
        remaining = self.config.total_steps - self.step
        values["perf/eta_seconds"] = remaining / steps_per_second if steps_per_second > 0 else 0.0
        self.store.record_metrics(run_id=self.run_id, step=self.step, values=values)
        self.update_sums.clear()
        self.update_count = 0
        self.finished_returns.clear()
        self.finished_successes.clear()
        self.log_time, self.log_step, self.log_updates = now, self.step, self.total_updates

    # ================================================================== control: heartbeat, stop, interrupt
    def _beat(self, status: str | None = None) -> bool:
        self.last_beat = time.monotonic()
        step = self.step if self.step_known else None
        return self.store.heartbeat(run_id=self.run_id, worker=self.worker, step=step, status=status)

    def _tick(self) -> None:
        """Heartbeat when one is due (also inside long steps); a refusal is acted on at the next step."""
        if time.monotonic() - self.last_beat >= self.config.heartbeat_seconds and not self._beat():
            self.beat_failed = True

    def _check_control(self) -> str | None:
        if self.interrupt.is_set():
            self._checkpoint()
            self._beat()  # the run shows the step it will resume at
            self.store.set_run_status(
                run_id=self.run_id, status=RunStatus.QUEUED, reason="learner interrupted", worker=self.worker
            )
            self._event(f"learner {self.worker} interrupted at step {self.step}: run queued again, it resumes here")
            return Outcome.REQUEUED
        if self.beat_failed:
            self.beat_failed = False
            return self._stop_or_lost()
        return None

    def _stop_or_lost(self) -> str:
        run = self.store.get_run(run_id=self.run_id)
        if run.worker == self.worker and run.status in RunStatus.ACTIVE and run.stop_requested:
            self._checkpoint()
            self._beat()
            self.store.set_run_status(run_id=self.run_id, status=RunStatus.STOPPED, worker=self.worker)
            return Outcome.STOPPED
        self._event(f"learner {self.worker} no longer holds the run (now {run.status}, {run.worker}); leaving it")
        return Outcome.LOST

    def _event(self, message: str, level: str = "info") -> None:
        """A progress message for the UI (the run's events) and the learner's console."""
        levels = {"error": logging.ERROR, "warning": logging.WARNING}
        logger.log(levels.get(level, logging.INFO), "run %s: %s", self.run_id, message)
        self.store.record_event(run_id=self.run_id, message=message, level=level)

    # ================================================================== checkpoints
    def _checkpoint(self) -> None:
        started = time.monotonic()
        size = save_checkpoint(self.checkpoint_file, self._state())
        seconds = time.monotonic() - started
        self._event(f"checkpoint written at step {self.step} ({size / 1e6:.1f} MB in {seconds:.1f} s)")
        self._tick()

    def _state(self) -> dict[str, Any]:
        return {
            "version": CHECKPOINT_VERSION,
            "config": json.dumps(self.config.to_dict()),
            "step": self.step,
            "total_updates": self.total_updates,
            "answer_cursor": self.answer_cursor,
            "naive_trained": self.naive_trained,
            "evaluated_step": self.evaluated_step,
            "agent": self.agent.state_dict(),
            "reward_model": self.reward_model.state_dict() if self.reward_model is not None else None,
            "selector": self.selector.state_dict() if self.selector is not None else None,
            "replay": self.replay.state_dict(),
            "rng": {
                "numpy": self.rng.bit_generator.state,
                "torch": torch.get_rng_state(),
                "cuda": _cuda_rng_states(self.agent.device),
                "env": _env_rng_state(self.env),
            },
        }

    def _restore(self, state: dict[str, Any]) -> None:
        if state.get("version") != CHECKPOINT_VERSION:
            raise ValueError(f"checkpoint {self.checkpoint_file} has an unknown version {state.get('version')}")
        self.step, self.total_updates = int(state["step"]), int(state["total_updates"])
        self.answer_cursor, self.naive_trained = int(state["answer_cursor"]), bool(state["naive_trained"])
        self.evaluated_step = int(state.get("evaluated_step", self.step))
        self.agent.load_state_dict(state["agent"])
        if self.reward_model is not None:
            self.reward_model.load_state_dict(state["reward_model"])
        if self.selector is not None:
            self.selector.load_state_dict(state["selector"])
        self.replay.load_state_dict(state["replay"])
        self.rng.bit_generator.state = state["rng"]["numpy"]
        torch.set_rng_state(state["rng"]["torch"])
        cuda = state["rng"].get("cuda")
        # (another host may have another number of GPUs: then each keeps its own streams)
        if cuda is not None and torch.cuda.is_available() and len(cuda) == torch.cuda.device_count():
            torch.cuda.set_rng_state_all(cuda)
        if state["rng"]["env"] is not None:
            self.env.reset(seed=self.config.seed)  # creates the env's generator, then continue its stream
            self.env.unwrapped.np_random.bit_generator.state = state["rng"]["env"]

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
            image = decode_image_at_size(goal.model_png)
            if image.shape[:2] != (size, size):  # the goal set's model size is not the run's: remake from original
                image = model_copy(goal.original, size)
                remade += 1
            images.append(image)
        self.reward_model.goals = np.stack(images)
        note = f" ({remade} remade at {size}x{size} px from their originals)" if remade else ""
        self._event(f"loaded {len(goals)} goal examples{note}")


def decode_image_at_size(data: bytes) -> np.ndarray:
    """PNG bytes -> uint8 HWC RGB at the size stored."""
    with Image.open(io.BytesIO(data)) as image:
        return np.array(image.convert("RGB"))


def model_copy(original: bytes, size: int) -> np.ndarray:
    """A goal example's model view made from its uploaded original the way the web app makes it (app/images.py
    to_png): upright, transparency flattened onto white, centre-cropped to a square, LANCZOS (area) resize."""
    with Image.open(io.BytesIO(original)) as opened:
        opened.load()
        image = ImageOps.exif_transpose(opened)
    if image.mode in ("RGBA", "LA") or (image.mode == "P" and "transparency" in image.info):
        rgba = image.convert("RGBA")
        background = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
        image = Image.alpha_composite(background, rgba)
    image = image.convert("RGB")
    width, height = image.size
    side = min(width, height)
    left, top = (width - side) // 2, (height - side) // 2
    square = image.crop((left, top, left + side, top + side))
    return np.array(square.resize((size, size), Image.Resampling.LANCZOS, reducing_gap=3.0))


def _cuda_rng_states(device: torch.device) -> list[torch.Tensor] | None:
    if device.type == "cuda" and torch.cuda.is_available():
        return torch.cuda.get_rng_state_all()
    return None


def _env_rng_state(env: Any) -> dict[str, Any] | None:
    try:
        return env.unwrapped.np_random.bit_generator.state
    except AttributeError:
        return None
