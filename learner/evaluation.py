"""Evaluation: `eval_episodes` deterministic episodes of the current policy on envs of its own.

The episodes run in lockstep, up to EVAL_LOCKSTEP at once on as many envs, so the policy acts on all of them in
one batch (one forward pass per env step instead of one per episode and step: a fifth of the network calls at
the default 5 episodes). Each episode keeps its own reset seed, so the episodes are those a one-after-another
evaluation runs (up to float rounding in the batched forward pass).

eval/return is the env's own reward summed; with a classifier, eval/classifier_return sums f_psi(s');
eval/success_rate is the success of each episode's final state (the paper's measure). The first episode is
recorded as the run page's rollout. An interrupt stops an evaluation without recording anything.
"""

from dataclasses import dataclass, field

import gymnasium
import numpy as np

from contract.config import EvaluationConfig, TaskConfig
from contract.envs import check_action_space, display_image, encode_gif, model_image, scale_action, success_of
from contract.store import Store
from learner.reward import RewardModel
from learner.run_control import RunControl
from learner.sac import SACAgent

EVAL_LOCKSTEP = 8
"""Evaluation episodes run together (each on its own env); more episodes run in groups of this many."""


def eval_env_count(config: EvaluationConfig) -> int:
    """How many envs an evaluation needs: one per episode run in lockstep (at least one)."""
    return max(1, min(config.eval_episodes, EVAL_LOCKSTEP))


@dataclass
class Episode:
    """One evaluation episode as it runs: its env's last observation, reward sum, f_psi inputs and frames."""

    obs: np.ndarray
    success: float | None
    frames: list[np.ndarray] = field(default_factory=list)
    next_obs: list[np.ndarray] = field(default_factory=list)
    total: float = 0.0
    done: bool = False


class Evaluator:
    """Runs and records evaluations of `agent` on `envs` (not the training env), in lockstep."""

    def __init__(
        self, config: EvaluationConfig, task: TaskConfig, *, envs: list[gymnasium.Env], agent: SACAgent,
        reward_model: RewardModel | None, store: Store, run_id: int, control: RunControl,
    ) -> None:  # fmt: skip
        """No `envs`: no episodes (a robot's are a person's Evaluate now)."""
        self.config, self.task, self.envs, self.agent, self.reward_model = config, task, envs, agent, reward_model
        self.episode_count = config.eval_episodes if envs else 0
        self.store, self.run_id, self.control = store, run_id, control
        self.action_space = check_action_space(envs[0]) if envs else None  # (none: eval_episodes is 0)

    def evaluate(self, step: int) -> bool:
        """Evaluate at env step `step` and record it; False when an interrupt cut it short (nothing recorded)."""
        episodes = self.run_episodes(step)
        if episodes is None:
            return False
        self.record(step, episodes)
        return True

    def run_episodes(self, step: int) -> list[Episode] | None:
        """The evaluation's episodes, `EVAL_LOCKSTEP` at a time; None when an interrupt cut them short. They read
        the policy only (f_psi is read by `record`, so it may train meanwhile on another thread)."""
        episodes: list[Episode] = []
        for first in range(0, self.episode_count, max(1, len(self.envs))):
            count = min(len(self.envs), self.episode_count - first)
            episodes += self._episodes(step, first, count)
            if self.control.interrupted:
                return None
            self.control.tick()
        return episodes

    def record(self, step: int, episodes: list[Episode]) -> None:
        """The evaluation's metrics (eval/classifier_return with the current f_psi), its rollout and its event."""
        if not episodes:  # (eval_episodes = 0)
            return
        returns = [episode.total for episode in episodes]
        successes = [episode.success for episode in episodes]
        frames = episodes[0].frames
        classifier_returns = []
        if self.reward_model is not None:
            classifier_returns = [float(self.reward_model.logits(np.stack(e.next_obs)).sum()) for e in episodes]
        values = {"eval/return": float(np.mean(returns))}
        if classifier_returns:
            values["eval/classifier_return"] = float(np.mean(classifier_returns))
        known = [s for s in successes if s is not None]
        if len(known) == len(successes):
            values["eval/success_rate"] = float(np.mean(known))
        self.store.record_metrics(run_id=self.run_id, step=step, values=values)
        self.store.record_rollout(
            run_id=self.run_id, env_step=step, data=encode_gif(frames), frame_count=len(frames),
            media_type="image/gif", episode_return=returns[0], success=successes[0],
        )  # fmt: skip
        rate = f", success rate {values['eval/success_rate']:.2f}" if "eval/success_rate" in values else ""
        self.control.event(f"evaluation at step {step}: return {values['eval/return']:.2f}{rate}")

    def _episodes(self, step: int, first: int, count: int) -> list[Episode]:
        """Episodes first .. first + count - 1 on as many envs, acting on all that are running in one batch."""
        cfg, task = self.config, self.task
        episodes = []
        for index, env in enumerate(self.envs[:count]):
            raw, info = env.reset(seed=task.seed * 100_003 + 1_000_000 + step + first + index)
            obs = model_image(raw, task.image_size, task.env_id)
            episode = Episode(obs=obs, success=success_of(info))
            if first + index == 0:  # the recorded rollout
                episode.frames.append(display_image(env, cfg.rollout_size, obs))
            episodes.append(episode)
        for _ in range(task.episode_steps):
            running = [index for index, episode in enumerate(episodes) if not episode.done]
            if not running or self.control.interrupted:
                break
            actions = self.agent.act_batch(np.stack([episodes[index].obs for index in running]), deterministic=True)
            self.control.tick()  # (a long evaluation keeps the run's heartbeat)
            for index, action in zip(running, actions, strict=True):
                env, episode = self.envs[index], episodes[index]
                raw, reward, terminated, truncated, info = env.step(scale_action(action, self.action_space))
                episode.obs = model_image(raw, task.image_size, task.env_id)
                episode.total += float(reward)
                episode.next_obs.append(episode.obs)
                episode.success = success_of(info)
                if first + index == 0:
                    episode.frames.append(display_image(env, cfg.rollout_size, episode.obs))
                episode.done = bool(terminated or truncated)
        return episodes
