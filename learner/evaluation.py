"""Evaluation: `eval_episodes` deterministic episodes of the current policy on an env of its own.

eval/return is the env's own reward summed; with a classifier, eval/classifier_return sums f_psi(s');
eval/success_rate is the success of each episode's final state (the paper's measure). The first episode is
recorded as the run page's rollout. An interrupt stops an evaluation without recording anything.
"""

import gymnasium
import numpy as np

from app.store import Store
from learner.config import TrainConfig
from learner.envs import check_action_space, display_image, encode_gif, model_image, scale_action, success_of
from learner.reward import RewardModel
from learner.run_control import RunControl
from learner.sac import SACAgent


class Evaluator:
    """Runs and records evaluations of `agent` on `env` (not the training env)."""

    def __init__(
        self, config: TrainConfig, *, env: gymnasium.Env, agent: SACAgent, reward_model: RewardModel | None,
        store: Store, run_id: int, control: RunControl,
    ) -> None:  # fmt: skip
        self.config, self.env, self.agent, self.reward_model = config, env, agent, reward_model
        self.store, self.run_id, self.control = store, run_id, control
        self.action_space = check_action_space(env)

    def evaluate(self, step: int) -> bool:
        """Evaluate at env step `step` and record it; False when an interrupt cut it short (nothing recorded)."""
        cfg = self.config
        if cfg.eval_episodes == 0:
            return True
        returns, classifier_returns, successes, frames = [], [], [], []
        for episode in range(cfg.eval_episodes):
            total, next_frames, success, episode_frames = self._episode(step, episode, record=episode == 0)
            if self.control.interrupted:
                return False
            returns.append(total)
            successes.append(success)
            frames = frames or episode_frames
            if self.reward_model is not None:
                classifier_returns.append(float(self.reward_model.logits(np.stack(next_frames)).sum()))
            self.control.tick()
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
        return True

    def _episode(self, step: int, episode: int, record: bool) -> tuple[float, list[np.ndarray], float | None, list]:
        cfg = self.config
        raw, info = self.env.reset(seed=cfg.seed * 100_003 + 1_000_000 + step + episode)
        obs = model_image(raw, cfg.image_size)
        frames = [display_image(self.env, cfg.rollout_size, obs)] if record else []
        total, next_frames, success = 0.0, [], success_of(info)
        for _ in range(cfg.episode_steps):
            if self.control.interrupted:
                break
            action = self.agent.act(obs, deterministic=True)
            raw, reward, terminated, truncated, info = self.env.step(scale_action(action, self.action_space))
            obs = model_image(raw, cfg.image_size)
            total += float(reward)
            next_frames.append(obs)
            success = success_of(info)
            if record:
                frames.append(display_image(self.env, cfg.rollout_size, obs))
            if terminated or truncated:
                break
        return total, next_frames, success, frames
