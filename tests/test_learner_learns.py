"""The learner learns: a small task trained by `raq learn`'s own code path ends well above a random policy, with the
env's success as the reward (SAC alone), and with VICE-RAQ's classifier as the only reward, trained from goal
examples and a person's answers."""

import functools

import gymnasium as gym
import numpy as np
from conftest import create_run, learn_once_beside
from test_learner_run import oracle

from contract.config import TrainConfig
from contract.settings import Settings
from contract.store import RunStatus, Store
from learner.testing_envs import DotReach
from learner.worker import work

ENV = "learner.testing_envs:DotReachRight-v0"
STEPS = 2000
VICE_STEPS = 3000


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


def right_goals(store: Store, count: int = 8) -> int:
    """A goal set of `count` photos of DotReachRight-v0 done (the dot inside the disc on the right), drawn by the
    env itself at 16 px: what a person would upload."""
    from contract.envs import encode_png  # noqa: PLC0415

    kwargs = gym.spec(ENV.split(":")[1]).kwargs
    env, rng = DotReach(obs_size=16, render_size=32, **kwargs), np.random.default_rng(1)
    goal_set = store.create_goal_set(name="right", image_size=16)
    for index in range(count):
        while True:  # (a success state, as the env judges it)
            env.position = rng.uniform(-1.0, 1.0, size=2).astype(np.float32)
            if env._info()["success"]:
                break
        store.add_goal_example(
            goal_set_id=goal_set.id, filename=f"goal{index}.png", original=encode_png(env._draw(16)),
            original_media_type="image/png", width=16, height=16, model_png=encode_png(env._draw(16)),
            display_png=encode_png(env._draw(32)),
        )  # fmt: skip
    return goal_set.id


def test_vice_raq_learns_a_small_task_from_goal_examples_and_answers_alone(
    dot_reach: tuple[Settings, Store, int],
) -> None:
    """The same task with no reward from the env: VICE-RAQ's classifier f_psi, trained on 8 goal photos against the
    policy's own replay and on the answers to its 20 questions, is SAC's only reward. After 3,000 env steps its
    evaluation success beats the random policy's by at least 0.3 (it reached 1.0, the random policy 0.21); with the
    classifier's rewards replaced by zeros (HostUpdates._rewards) it ended at 0.0."""
    settings, store, _ = dot_reach
    config = TrainConfig(
        env_id=ENV, algorithm="vice_raq", seed=0, image_size=16, conv_filters=8, hidden_dim=32, batch_size=32,
        total_steps=VICE_STEPS, episode_steps=25, initial_random_steps=200, eval_every=VICE_STEPS // 2,
        eval_episodes=20, checkpoint_every=10 * VICE_STEPS, log_every=200, display_size=32, rollout_size=16,
        replay_capacity=10_000, heartbeat_seconds=1.0, classifier_batch_size=32, classifier_steps=50,
        epoch_steps=100, query_every=100, query_budget=20, query_candidates=16, raq_initial_negatives=200,
    )  # fmt: skip
    run_id = create_run(store, right_goals(store), config)
    assert learn_once_beside(settings, functools.partial(oracle, store, run_id)) == 0
    assert store.get_run(run_id=run_id).status == RunStatus.FINISHED
    rates = {m.step: m.value for m in store.metrics(run_id=run_id, names=["eval/success_rate"])}
    random = random_policy_success()
    assert rates[VICE_STEPS] >= random + 0.3, (rates, random)
