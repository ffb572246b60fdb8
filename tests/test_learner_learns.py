"""The learner learns: a small task trained by `raq learn`'s own code path ends well above a random policy."""

import gymnasium as gym
import numpy as np
from conftest import create_run

from contract.config import TrainConfig
from contract.settings import Settings
from contract.store import RunStatus, Store
from learner.worker import work

ENV = "learner.testing_envs:DotReachRight-v0"
STEPS = 2000


def random_policy_success(episodes: int = 200) -> float:
    """The success rate of uniformly random actions on the task, measured here."""
    import learner.testing_envs  # noqa: F401, PLC0415 - registers the task

    env, rng, successes = gym.make(ENV.split(":")[1]), np.random.default_rng(0), []
    for episode in range(episodes):
        env.reset(seed=episode)
        truncated, terminated = False, False
        while not (terminated or truncated):
            _, _, terminated, truncated, info = env.step(rng.uniform(-1.0, 1.0, size=2).astype(np.float32))
        successes.append(float(info["success"]))
    return float(np.mean(successes))


def test_sac_learns_a_small_task_far_beyond_a_random_policy(dot_reach: tuple[Settings, Store, int]) -> None:
    """Seed 0 of a 16 px dot pushed right (the env's success as the reward): after 2,000 env steps the policy's
    evaluation success beats the random policy's by at least 0.3. A learner whose SAC rewards were all zero ends at
    0.0 here (its policy stays put), a random one near 0.2."""
    settings, store, _ = dot_reach
    config = TrainConfig(
        env_id=ENV, algorithm="sparse", seed=0, image_size=16, conv_filters=8, hidden_dim=32, batch_size=32,
        total_steps=STEPS, episode_steps=25, initial_random_steps=200, eval_every=STEPS // 2, eval_episodes=20,
        checkpoint_every=10 * STEPS, log_every=200, display_size=32, rollout_size=16, replay_capacity=10_000,
        heartbeat_seconds=1.0,
    )  # fmt: skip
    run_id = create_run(store, None, config)
    assert work(settings, worker_name="w", once=True) == 0
    assert store.get_run(run_id=run_id).status == RunStatus.FINISHED
    rates = {m.step: m.value for m in store.metrics(run_id=run_id, names=["eval/success_rate"])}
    random = random_policy_success()
    assert 0.05 < random < 0.5  # (the task is neither solved nor hopeless by chance)
    assert rates[STEPS] >= random + 0.3, (rates, random)
