"""The lockstep runner: simulated envs stepped in lockstep with the SAC updates, as fast as the host allows.

Per batch of env steps (one per training env): act (uniformly at random for the first initial_random_steps,
coloured by the episode's noise), step the envs, and run the updates_per_step SAC updates due for them on the
replay as it was before the steps. With the update thread (the CPU's default) the updates run on it while this
thread acts (on a copy of pi synced before the updates start: the same pi the step would act with), steps the
envs and scores the query candidates waiting for a batch (MuJoCo leaves the GIL, so a second core does that);
at an epoch's end f_psi trains on it while the evaluation's episodes run here. On a GPU the updates are CUDA
graph launches, asynchronous already, and run on this thread after the steps.
"""

import contextlib
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np
import torch

from contract.config import TrainConfig
from contract.envs import make_env, scale_action
from contract.store import Store
from learner.evaluation import eval_env_count
from learner.exploration import EpisodeNoise, warm_up_action
from learner.run_control import RunControl
from learner.trainer import EnvEpisode, EnvStep, Trainer, env_seed
from learner.updates import HostUpdates


class LockstepRunner:
    """Steps the run's simulated envs and its SAC updates together; owns the envs and the update thread."""

    def __init__(
        self, config: TrainConfig, *, store: Store, control: RunControl, goal_set_id: int | None,
        checkpoint_file: Path | str,
    ) -> None:  # fmt: skip
        execution, size = config.execution, config.image_size
        self.episodes = [EnvEpisode(make_env(config.env_id, image_size=size, display_size=config.display_size))
                         for _ in range(execution.num_envs)]  # fmt: skip
        eval_envs = [  # their renders are the rollout's frames only: drawn at that size (2 ms, not 5)
            make_env(config.env_id, image_size=size, display_size=config.rollout_size)
            for _ in range(eval_env_count(config.evaluation))
        ]
        self.trainer = trainer = Trainer(
            config, store=store, control=control, goal_set_id=goal_set_id, checkpoint_file=checkpoint_file,
            episodes=self.episodes, eval_envs=eval_envs,
        )  # fmt: skip
        self.initial_random_steps = config.initial_random_steps
        on_thread = execution.update_thread == "on" or (
            execution.update_thread == "auto" and trainer.agent.device.type != "cuda"
        )
        self.update_thread = ThreadPoolExecutor(1, thread_name_prefix="sac-updates") if on_thread else None
        # beside the updates, acting reads a copy of pi (synced per batch), drawing from the run's acting generator
        self.acting_copy = trainer.agent.policy_copy(trainer.acting_generator) if on_thread else None
        if isinstance(trainer.updates, HostUpdates):  # (the device's graphs keep to one thread)
            trainer.classifier_thread = self.update_thread
        if config.exploration_noise_beta > 0:  # each env's coloured eps, from the acting generator (else i.i.d.)
            for episode in self.episodes:
                episode.noise = EpisodeNoise(
                    config.exploration_noise_beta, config.episode_steps, trainer.action_dim, trainer.acting_generator
                )

    def start(self, *, resumed: bool) -> None:
        """Every env's first episode (seeded on a fresh run; a resumed one continues its envs' streams)."""
        for index, episode in enumerate(self.episodes):
            self.begin_episode(episode, seed=None if resumed else env_seed(self.trainer.config.seed, index))

    def begin_episode(self, episode: EnvEpisode, seed: int | None = None) -> None:
        raw, info = episode.env.reset(seed=seed)
        self.trainer.start_episode(episode, raw, info)

    def steps(self, count: int) -> list[EnvStep]:
        """The first `count` envs' actions and steps (physics and render in one burst: on a GPU not between the
        update graphs), and the SAC updates due for them."""
        trainer, episodes = self.trainer, self.episodes[:count]
        step = trainer.counters.step
        updates = trainer.updates_due_by(step + count) - trainer.updates_due_by(step)
        beside = self.update_thread is not None and updates > 0
        if self.acting_copy is not None:
            self.acting_copy.sync()  # pi as the last batch's updates left it (none is running now)
        # the warm-up's uniform actions come from the run's generator, which the updates draw from: before them
        actions = self._actions(episodes) if step < self.initial_random_steps or not beside else None
        pending: Future[None] | None = None
        if beside:
            assert self.update_thread is not None
            pending = self.update_thread.submit(trainer.sac_updates, updates)
        try:
            if actions is None:
                actions = self._actions(episodes)
            space = trainer.action_space
            outcomes = [episode.env.step(scale_action(a, space)) for episode, a in zip(episodes, actions, strict=True)]
            if trainer.queries is not None:
                trainer.queries.score_full_batch()
        finally:
            if pending is not None:
                pending.result()  # (an update's error is raised here)
        if pending is None and updates:
            trainer.sac_updates(updates)
        return [EnvStep(*step) for step in zip(episodes, actions, outcomes, strict=True)]

    def _actions(self, episodes: list[EnvEpisode]) -> np.ndarray:
        """One action per env: uniformly random during the warm-up, else the policy's, in one batch. With coloured
        noise (exploration_noise_beta) both take each env's next eps: the warm-up's as U(-1, 1) through the CDF."""
        trainer, first = self.trainer, self.trainer.counters.step
        actions = np.empty((len(episodes), trainer.action_dim), dtype=np.float32)
        sources = [episode.noise for episode in episodes if episode.noise is not None]
        noise = torch.stack([source.next() for source in sources]) if sources else None
        random = [index for index in range(len(episodes)) if first + index < self.initial_random_steps]
        for index in random:
            actions[index] = warm_up_action(None if noise is None else noise[index], trainer.rng, trainer.action_dim)
        acting = [index for index in range(len(episodes)) if index not in random]
        if acting:
            observations = np.stack([episodes[index].obs for index in acting])
            eps = None if noise is None else noise[acting]
            if self.acting_copy is not None:  # (beside the updates: the copy of pi)
                actions[acting] = self.acting_copy.act_batch(observations, noise=eps)
            else:
                actions[acting] = trainer.agent.act_batch(observations, generator=trainer.acting_generator, noise=eps)
        return actions

    def close(self) -> None:
        if self.update_thread is not None:
            self.update_thread.shutdown()
        for env in (*(episode.env for episode in self.episodes), *self.trainer.eval_envs):
            with contextlib.suppress(Exception):  # closing must not hide the error that ended training
                env.close()
