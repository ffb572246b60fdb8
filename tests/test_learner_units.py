"""Learner parts on small synthetic data: losses, mixup, the AIRL logit, replay, query selection."""

import copy
import io
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from PIL import Image

from contract.config import TrainConfig
from contract.envs import encode_gif
from learner.exploration import EpisodeNoise, colored_noise, uniform_of
from learner.networks import (
    _matmul_seconds,
    input_dtype,
    mlp,
    precision_autocast,
    resolve_precision,
    squashed_gaussian_sample,
    to_float,
)
from learner.queries import QuerySelector
from learner.replay import ReplayBuffer, edge_pad, random_shift
from learner.reward import RewardModel, mixup
from learner.sac import SACAgent

torch.set_num_threads(1)
SIZE = 16


def tiny(**overrides: object) -> TrainConfig:
    values: dict[str, object] = dict(
        image_size=SIZE, conv_filters=4, hidden_dim=32, batch_size=16, classifier_batch_size=16, precision="fp32"
    )
    values.update(overrides)
    return TrainConfig(**values)  # type: ignore[arg-type]


def goal_like(rng: np.random.Generator, count: int) -> np.ndarray:
    """Dark noise with a bright green square: the 'goal' class."""
    images = rng.integers(0, 60, size=(count, SIZE, SIZE, 3), dtype=np.uint8)
    images[:, 4:12, 4:12, 1] = 230
    return images


def replay_like(rng: np.random.Generator, count: int) -> np.ndarray:
    """Dark noise with a red square somewhere: the 'replay' class."""
    images = rng.integers(0, 60, size=(count, SIZE, SIZE, 3), dtype=np.uint8)
    for image, (y, x) in zip(images, rng.integers(0, 8, size=(count, 2)), strict=True):
        image[y : y + 8, x : x + 8, 0] = 230
    return images


# ---------------------------------------------------------------------------------------------- classifier
@pytest.mark.parametrize("algorithm", ["raq", "vice_raq"])
def test_classifier_separates_goals_from_negatives(algorithm: str) -> None:
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    config = tiny(algorithm=algorithm, classifier_lr=1e-3)
    model = RewardModel.for_run(config, rng)
    agent = SACAgent.for_run(config, action_dim=2)
    policy = agent.policy if model.airl else None
    goals, negatives = goal_like(rng, 64), replay_like(rng, 64)
    for _ in range(60):
        pick = rng.integers(0, 64, size=16)
        metrics = model.update_classifier(goals[pick], negatives[pick], policy)
    assert set(metrics) >= {"reward/loss", "reward/acc_goal", "reward/acc_replay", "reward/mean_logit_goal"}
    # without the accuracy pass: the same step, only the loss reported
    pick = rng.integers(0, 64, size=16)
    assert set(model.update_classifier(goals[pick], negatives[pick], policy, accuracy=False)) == {"reward/loss"}
    test_goals, test_negatives = model.logits(goal_like(rng, 32)), model.logits(replay_like(rng, 32))
    assert test_goals.min() > test_negatives.max()
    if not model.airl:  # plain BCE: f itself is the classifier
        assert (test_goals > 0).mean() > 0.9 and (test_negatives < 0).mean() > 0.9


@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
def test_mixup_mixes_images_and_labels_with_the_same_lambda(dtype: torch.dtype) -> None:
    images = torch.rand(8, 3, SIZE, SIZE).to(dtype)
    labels = torch.tensor([1.0] * 4 + [0.0] * 4)
    mixed_images, mixed_labels = mixup(images, labels, 1.0, np.random.default_rng(3))
    replay_rng = np.random.default_rng(3)
    lam = torch.from_numpy(replay_rng.beta(1.0, 1.0, size=8).astype(np.float32)).to(dtype).float()  # as rounded
    perm = torch.from_numpy(replay_rng.permutation(8))
    wide = images.float()
    expected = lam.view(-1, 1, 1, 1) * wide + (1 - lam.view(-1, 1, 1, 1)) * wide[perm]
    assert mixed_images.dtype == dtype and mixed_labels.dtype == torch.float32
    tolerance = {"atol": 1e-2, "rtol": 1e-2} if dtype == torch.bfloat16 else {}
    torch.testing.assert_close(mixed_images.float(), expected, **tolerance)
    torch.testing.assert_close(mixed_labels, lam * labels + (1 - lam) * labels[perm])
    assert ((mixed_labels >= 0) & (mixed_labels <= 1)).all()
    low, high = torch.minimum(wide, wide[perm]), torch.maximum(wide, wide[perm])
    slack = 1e-2 if dtype == torch.bfloat16 else 1e-6
    assert ((mixed_images.float() >= low - slack) & (mixed_images.float() <= high + slack)).all()
    assert not torch.equal(mixed_labels, labels)  # it did mix
    same, same_labels = mixup(images, labels, 0.0, np.random.default_rng(3))
    assert same is images and same_labels is labels


def test_vice_logit_is_f_minus_log_pi_of_a_fresh_action() -> None:
    torch.manual_seed(1)
    config = tiny(algorithm="vice")
    model = RewardModel.for_run(config, np.random.default_rng(0))
    agent = SACAgent.for_run(config, action_dim=3)
    images = to_float(replay_like(np.random.default_rng(1), 6))
    torch.manual_seed(7)
    logits, f, log_pi = model.discriminator_logits(images, agent.policy)
    assert log_pi is not None
    torch.testing.assert_close(logits, f - log_pi)
    # log pi of the sampled action, computed independently from the tanh-Gaussian density
    torch.manual_seed(7)
    action, _ = agent.policy(images)
    with torch.no_grad():
        mean, log_std = agent.actor(agent._features(images))
    u = torch.atanh(action.clamp(-1 + 1e-6, 1 - 1e-6))
    density = torch.distributions.Normal(mean, log_std.exp()).log_prob(u).sum(-1)
    expected = density - torch.log(1 - action.pow(2) + 1e-12).sum(-1)
    torch.testing.assert_close(log_pi, expected, atol=1e-3, rtol=1e-3)

    # the loss that update_classifier minimises uses that logit: with a policy of known log pi = c,
    # the loss is BCE(f - c, y) (no mixup here so the batch is the unmixed one)
    config = tiny(algorithm="vice", mixup_alpha=0.0)
    model = RewardModel.for_run(config, np.random.default_rng(0))
    positives, negatives = goal_like(np.random.default_rng(2), 4), replay_like(np.random.default_rng(3), 4)
    batch = to_float(np.concatenate([positives, negatives]))
    with torch.no_grad():
        f = model.net(batch)
    c = 1.7

    def known_policy(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return torch.zeros(len(x), 2), torch.full((len(x),), c)

    metrics = model.update_classifier(positives, negatives, known_policy)
    labels = torch.tensor([1.0] * 4 + [0.0] * 4)
    assert metrics["reward/loss"] == pytest.approx(F.binary_cross_entropy_with_logits(f - c, labels).item(), rel=1e-5)
    assert metrics["reward/mean_log_pi"] == pytest.approx(c)


def test_squashed_gaussian_log_prob_matches_change_of_variables() -> None:
    torch.manual_seed(0)
    mean, log_std = torch.randn(5, 2) * 0.5, torch.randn(5, 2) * 0.3 - 0.5
    torch.manual_seed(1)
    action, log_pi = squashed_gaussian_sample(mean, log_std)
    torch.manual_seed(1)
    u = mean + log_std.exp() * torch.randn_like(mean)
    density = torch.distributions.Normal(mean, log_std.exp()).log_prob(u).sum(-1)
    expected = density - torch.log(1 - torch.tanh(u) ** 2).sum(-1)
    torch.testing.assert_close(action, torch.tanh(u))
    torch.testing.assert_close(log_pi, expected, atol=1e-4, rtol=1e-4)


# ---------------------------------------------------------------------------------------------- exploration
@pytest.mark.parametrize("steps", [100, 101])
def test_coloured_noise_keeps_unit_variance_and_its_steps_agree_more_the_redder_it_is(steps: int) -> None:
    """Each step ~ N(0, 1) whatever beta; the correlation of neighbouring steps: ~0 for white, high for pink,
    higher for red; the sequences of one generator differ, and the same seed draws the same."""
    generator = torch.Generator().manual_seed(0)
    lag_one = {}
    for beta in (0.0, 1.0, 2.0):
        noise = torch.stack([colored_noise(beta, steps, 2, generator) for _ in range(1000)])
        assert noise.shape == (1000, steps, 2)
        assert abs(noise.var(dim=0).mean().item() - 1.0) < 0.05 and abs(noise.mean().item()) < 0.05
        lag_one[beta] = (noise[:, 1:] * noise[:, :-1]).mean().item()
    assert abs(lag_one[0.0]) < 0.03 and 0.5 < lag_one[1.0] < 0.8 and lag_one[2.0] > 0.9, lag_one
    first, second = (colored_noise(1.0, steps, 2, torch.Generator().manual_seed(3)) for _ in range(2))
    assert torch.equal(first, second)
    assert not torch.equal(first, colored_noise(1.0, steps, 2, generator))
    uniform = uniform_of(torch.stack([colored_noise(1.0, steps, 1, generator) for _ in range(500)]))
    assert uniform.abs().max() < 1 and abs(uniform.abs().mean().item() - 0.5) < 0.03  # U(-1, 1): E|u| = 1/2


def test_episode_noise_runs_a_sequence_in_order_and_draws_a_new_one_past_its_end_or_at_a_restart() -> None:
    source = EpisodeNoise(1.0, 10, 3, torch.Generator().manual_seed(0))
    source.restart()
    sequence = source.sequence
    taken = torch.stack([source.next() for _ in range(10)])
    assert torch.equal(taken, sequence)
    beyond = source.next()
    assert not torch.equal(source.sequence, sequence) and torch.equal(beyond, source.sequence[0])
    source.restart()
    assert source.position == 0 and torch.equal(source.next(), source.sequence[0])


def test_acting_with_given_noise_is_tanh_of_mean_plus_std_times_it() -> None:
    """act_batch(noise=eps): a = tanh(mean + std * eps) for each observation's row of eps; zero eps: the mean
    action; torch's generator untouched."""
    agent = SACAgent.for_run(tiny(), 2)
    observations = np.random.default_rng(0).integers(0, 256, (3, SIZE, SIZE, 3), dtype=np.uint8)
    with torch.no_grad():
        mean, log_std = agent.actor(agent.encoder(agent.images(observations)))
    eps = torch.tensor([[0.0, 0.0], [1.0, -1.0], [2.0, 0.5]])
    state = torch.get_rng_state()
    actions = agent.act_batch(observations, noise=eps)
    assert torch.equal(torch.get_rng_state(), state)
    expected = torch.tanh(mean.float() + log_std.float().exp() * eps).numpy()
    np.testing.assert_allclose(actions, expected, atol=1e-5)
    np.testing.assert_allclose(actions[0], agent.act_batch(observations[:1], deterministic=True)[0], atol=1e-6)


# ---------------------------------------------------------------------------------------------- SAC
@pytest.mark.parametrize("shared", [True, False])
def test_critic_fits_the_soft_bellman_target_and_alpha_moves(shared: bool) -> None:
    torch.manual_seed(0)
    config = tiny(shared_encoder=shared, critic_lr=3e-3, precision="bf16" if shared else "fp32")
    agent = SACAgent.for_run(config, action_dim=2)
    rng = np.random.default_rng(0)
    obs, next_obs = agent.images(replay_like(rng, 16)), agent.images(replay_like(rng, 16))  # bf16 when shared
    action = torch.from_numpy(rng.uniform(-1, 1, (16, 2)).astype(np.float32))
    reward, terminal = torch.full((16,), 2.0), torch.zeros(16)  # y = r on terminal transitions
    first = agent.update_critic(obs, action, reward, next_obs, terminal)[0]["critic/loss"]
    for _ in range(60):
        metrics, actor_inputs = agent.update_critic(obs, action, reward, next_obs, terminal)
    assert metrics["critic/loss"] < 0.1 * first
    with torch.no_grad(), agent.autocast():
        q1, q2 = agent.critic(agent._features(obs), action)
    assert abs(q1.mean().item() - 2.0) < 0.3 and abs(q2.mean().item() - 2.0) < 0.3
    critic_before = [p.clone() for p in agent.critic.parameters()]
    grads_before = [p.grad.clone() for p in agent.critic.parameters()]
    # the actor step leaves the critic alone; alpha falls when the entropy is above the target
    agent.target_entropy = -100.0
    out = agent.update_actor_and_alpha(actor_inputs)
    assert set(out) >= {"actor/loss", "alpha/value"} and math.isfinite(out["actor/loss"])
    assert out["alpha/value"] < config.initial_alpha
    assert all(torch.equal(a, b) for a, b in zip(critic_before, agent.critic.parameters(), strict=True))
    assert all(torch.equal(g, p.grad) for g, p in zip(grads_before, agent.critic.parameters(), strict=True))
    target_before = [p.clone() for p in agent.critic_target.parameters()]
    agent.update_target()
    pairs = zip(agent.critic_target.parameters(), agent.critic.parameters(), strict=True)
    for old, (new, online) in zip(target_before, pairs, strict=True):
        torch.testing.assert_close(new, old + config.tau * (online - old))


@pytest.mark.parametrize("shared", [True, False])
def test_critic_target_bootstraps_through_non_terminal_transitions(shared: bool) -> None:
    """y = r + gamma (min_j Q'_j(s', a') - alpha log pi(a'|s')), a' ~ pi(.|s'), with not_done = 1: computed here
    from the target critic (made to differ from the online one), the same torch seed for a', alpha != 1."""
    torch.manual_seed(0)
    config = tiny(shared_encoder=shared, precision="fp32", discount=0.9)
    agent = SACAgent.for_run(config, action_dim=2)
    with torch.no_grad():
        agent.log_alpha.fill_(math.log(0.3))
        for p in agent.critic_target.parameters():
            p.add_(0.1 * torch.randn_like(p))
    rng = np.random.default_rng(1)
    obs, next_obs = to_float(replay_like(rng, 16)), to_float(replay_like(rng, 16))
    action = torch.from_numpy(rng.uniform(-1, 1, (16, 2)).astype(np.float32))
    reward = torch.from_numpy(rng.normal(size=16).astype(np.float32))
    not_done = torch.ones(16)
    with torch.no_grad():
        features = agent.encoder(next_obs) if shared else next_obs
        mean, log_std = agent.actor(features)
        torch.manual_seed(123)
        u = mean + log_std.exp() * torch.randn_like(mean)
        next_action = torch.tanh(u)
        normal = torch.distributions.Normal(mean, log_std.exp()).log_prob(u).sum(-1)
        log_pi = normal - torch.log(1 - next_action.pow(2)).sum(-1)
        q1, q2 = agent.critic_target(features, next_action)
        online1, _ = agent.critic(features, next_action)
        expected = reward + 0.9 * (torch.min(q1, q2) - 0.3 * log_pi)
    assert not torch.allclose(online1, q1)  # the target critic is what must be used
    torch.manual_seed(123)
    metrics, _ = agent.update_critic(obs, action, reward, next_obs, not_done)
    assert metrics["critic/target_mean"] == pytest.approx(expected.mean().item(), rel=1e-4, abs=1e-4)
    # and a terminal transition does not bootstrap
    torch.manual_seed(123)
    metrics, _ = agent.update_critic(obs, action, reward, next_obs, torch.zeros(16))
    assert metrics["critic/target_mean"] == pytest.approx(reward.mean().item(), rel=1e-5, abs=1e-6)


@pytest.mark.parametrize("shared", [True, False])
def test_a_checkpoint_from_before_the_twin_q_ensemble_loads_with_the_same_q_values_and_adam_state(shared: bool) -> None:
    """Runs checkpointed when q1 and q2 were two nn.Sequential MLPs resume: both Q's, the target Q's and every
    Adam state entry, with the shared encoder (default) and with the critic's own two encoders (paper)."""
    torch.manual_seed(0)
    config = tiny(shared_encoder=shared, precision="fp32", critic_layer_norm=False)  # (no LayerNorm back then)
    agent = SACAgent.for_run(config, action_dim=2)
    old = torch.nn.Module()  # the critic as it was: [encoders,] q1, q2
    if not shared:
        old.encoders = copy.deepcopy(agent.critic.encoders)
    feature_dim = agent.encoder.output_dim if shared else agent.critic.encoders[0].output_dim
    old.q1, old.q2 = mlp(feature_dim + 2, 32, 1), mlp(feature_dim + 2, 32, 1)
    old_target = copy.deepcopy(old)
    with torch.no_grad():
        for parameter in old_target.parameters():
            parameter.add_(0.1 * torch.randn_like(parameter))
    shared_params = list(agent.encoder.parameters()) if shared else []
    optimizer = torch.optim.Adam([*old.parameters(), *shared_params], lr=1e-3)
    images, action = agent.images(replay_like(np.random.default_rng(1), 8)), torch.rand(8, 2)

    def old_q(critic: torch.nn.Module) -> tuple[torch.Tensor, torch.Tensor]:
        h1 = h2 = agent.encoder(images) if shared else None
        if not shared:
            h1, h2 = critic.encoders[0](images), critic.encoders[1](images)
        return critic.q1(torch.cat([h1, action], -1)).squeeze(-1), critic.q2(torch.cat([h2, action], -1)).squeeze(-1)

    q1, q2 = old_q(old)
    (q1.sum() + 2 * q2.sum()).backward()
    optimizer.step()
    state = agent.state_dict()
    state.update(critic=old.state_dict(), critic_target=old_target.state_dict(), critic_opt=optimizer.state_dict())
    restored = SACAgent.for_run(config, action_dim=2)
    restored.load_state_dict(state)
    with torch.no_grad():
        for new_critic, old_critic in ((restored.critic, old), (restored.critic_target, old_target)):
            for new_q, old_q_value in zip(
                new_critic(restored._features(images), action), old_q(old_critic), strict=True
            ):
                torch.testing.assert_close(new_q, old_q_value)
    adam = restored.critic_opt.state
    for layer, sequential_index in enumerate((0, 2, 4)):
        for member, old_mlp in enumerate((old.q1, old.q2)):
            for kind, as_ensemble in (("weight", lambda t: t.t()), ("bias", lambda t: t[None])):
                converted = adam[getattr(restored.critic.layers[layer], kind)]
                original = optimizer.state[getattr(old_mlp[sequential_index], kind)]
                assert set(converted) == set(original)
                torch.testing.assert_close(converted["step"], original["step"])
                for key in ("exp_avg", "exp_avg_sq"):
                    torch.testing.assert_close(converted[key][member], as_ensemble(original[key]))
    encoders = (restored.encoder, agent.encoder) if shared else (restored.critic.encoders, old.encoders)
    for new_parameter, old_parameter in zip(encoders[0].parameters(), encoders[1].parameters(), strict=True):
        for key in ("exp_avg", "exp_avg_sq"):
            torch.testing.assert_close(adam[new_parameter][key], optimizer.state[old_parameter][key])
    rng = np.random.default_rng(0)
    obs, next_obs = restored.images(replay_like(rng, 16)), restored.images(replay_like(rng, 16))
    metrics = restored.update(obs, torch.rand(16, 2), torch.ones(16), next_obs, torch.ones(16))
    assert math.isfinite(metrics["critic/loss"])


# ---------------------------------------------------------------------------------------------- replay
def test_replay_stores_each_frame_once_and_shifts_like_drq() -> None:
    rng = np.random.default_rng(0)
    replay = ReplayBuffer(capacity=10, image_shape=(SIZE, SIZE, 3), action_dim=2)
    frames = replay_like(rng, 4)
    slots = [replay.add_frame(f) for f in frames]
    for i in range(3):
        replay.add(slots[i], np.full(2, i, np.float32), slots[i + 1], terminated=i == 2, env_reward=float(i == 2))
    assert replay.frames_added == 4 and len(replay) == 3
    batch = replay.sample(rng, 32)
    for j, index in enumerate(batch.indices):
        np.testing.assert_array_equal(batch.obs[j], frames[index])
        np.testing.assert_array_equal(batch.next_obs[j], frames[index + 1])
        assert batch.not_done[j] == (0.0 if index == 2 else 1.0)
    # a checkpoint written when the replay kept only success(s') (as "success") loads it as the env's figure
    older = {**replay.state_dict()}
    older["success"] = older.pop("env_reward")
    reloaded = ReplayBuffer(capacity=10, image_shape=(SIZE, SIZE, 3), action_dim=2)
    reloaded.load_state_dict(older)
    np.testing.assert_array_equal(reloaded.env_reward[:3], [0.0, 0.0, 1.0])
    # random shift == replicate-pad by `pad` then crop at a random offset
    shifted = random_shift(frames, 2, np.random.default_rng(5))
    offsets = np.random.default_rng(5).integers(0, 5, size=(4, 2))
    padded = np.pad(frames, ((0, 0), (2, 2), (2, 2), (0, 0)), mode="edge")
    for k, (dy, dx) in enumerate(offsets):
        np.testing.assert_array_equal(shifted[k], padded[k, dy : dy + SIZE, dx : dx + SIZE])
    for pad in (1, 2, 3, 4):  # corners included
        expected = np.pad(frames, ((0, 0), (pad, pad), (pad, pad), (0, 0)), mode="edge")
        np.testing.assert_array_equal(edge_pad(frames, pad), expected)
    # every offset, the extreme ones included, over a larger batch
    many = replay_like(rng, 200)
    shifted = random_shift(many, 2, np.random.default_rng(7))
    offsets = np.random.default_rng(7).integers(0, 5, size=(200, 2))
    assert len({tuple(offset) for offset in offsets}) == 25
    padded = np.pad(many, ((0, 0), (2, 2), (2, 2), (0, 0)), mode="edge")
    for k, (dy, dx) in enumerate(offsets):
        np.testing.assert_array_equal(shifted[k], padded[k, dy : dy + SIZE, dx : dx + SIZE])


def raq_model_and_replay(
    rng: np.random.Generator, capacity: int, transitions: int
) -> tuple[RewardModel, ReplayBuffer, np.ndarray]:
    """A raq reward model and a replay of `transitions` consecutive transitions over fresh frames."""
    model = RewardModel.for_run(tiny(algorithm="raq"), rng)
    replay = ReplayBuffer(capacity=capacity, image_shape=(SIZE, SIZE, 3), action_dim=2)
    frames = replay_like(rng, transitions + 1)
    slots = [replay.add_frame(f) for f in frames]
    for i in range(transitions):
        replay.add(slots[i], np.zeros(2, np.float32), slots[i + 1], False, None)
    return model, replay, frames


def test_reward_cache_is_exact_per_classifier_version() -> None:
    rng = np.random.default_rng(0)
    model, replay, frames = raq_model_and_replay(rng, capacity=50, transitions=20)
    indices = np.array([0, 5, 5, 19])
    np.testing.assert_allclose(model.rewards(replay, indices), model.logits(frames[indices + 1]), rtol=1e-5)
    model.update_classifier(goal_like(rng, 8), replay_like(rng, 8))
    np.testing.assert_allclose(model.rewards(replay, indices), model.logits(frames[indices + 1]), rtol=1e-5)


def test_an_unpublished_classifier_step_leaves_the_live_f_psi_and_its_rewards_as_they_were() -> None:
    """Steps with publish=False train the trainee only: rewards and logits (the live f_psi) and the version stay;
    publish makes the live f_psi the trainee's, and the cached rewards follow."""
    rng = np.random.default_rng(0)
    model, replay, frames = raq_model_and_replay(rng, capacity=50, transitions=20)
    indices = np.arange(20)
    before, version = model.rewards(replay, indices).copy(), model.version
    for _ in range(3):
        model.update_classifier(goal_like(rng, 8), replay_like(rng, 8), publish=False)
    np.testing.assert_array_equal(model.rewards(replay, indices), before)
    assert model.version == version
    trained = model.trainee(model.images(frames[1:21])).float().detach().numpy()
    model.publish()
    assert model.version == version + 1
    after = model.rewards(replay, indices)
    assert not np.allclose(after, before)
    np.testing.assert_allclose(after, trained, rtol=1e-5, atol=1e-6)


def test_a_policy_copy_keeps_its_weights_until_synced_and_draws_from_its_own_generator() -> None:
    """SACAgent.policy_copy: the actor as it was (a later change to the agent does not reach it until `sync`), its
    actions drawn from the given generator only (the same seed, the same actions; torch's generator untouched)."""
    agent = SACAgent.for_run(tiny(), 2)
    observations = np.random.default_rng(0).integers(0, 256, (4, SIZE, SIZE, 3), dtype=np.uint8)
    images = agent.images(observations)
    frozen = agent.policy_copy(torch.Generator().manual_seed(5))
    again = agent.policy_copy(torch.Generator().manual_seed(5))
    before = agent.act_batch(observations, deterministic=True)
    with torch.no_grad():
        for parameter in agent.actor.parameters():
            parameter.add_(1.0)
    state = torch.get_rng_state()
    (a1, log_pi1), (a2, log_pi2) = frozen(images), again(images)
    assert torch.equal(torch.get_rng_state(), state)
    assert torch.equal(a1, a2) and torch.equal(log_pi1, log_pi2)
    changed, _ = agent.policy(images, deterministic=True)
    assert not torch.allclose(changed.float(), a1.float(), atol=1e-2)
    np.testing.assert_array_equal(frozen.act_batch(observations, deterministic=True), before)
    frozen.sync()
    np.testing.assert_array_equal(
        frozen.act_batch(observations, deterministic=True), agent.act_batch(observations, deterministic=True)
    )


def test_reward_cache_is_not_stale_after_a_ring_wrap_or_a_checkpoint_round_trip() -> None:
    rng = np.random.default_rng(0)
    model, replay, frames = raq_model_and_replay(rng, capacity=5, transitions=5)
    everything = np.arange(5)
    np.testing.assert_allclose(model.rewards(replay, everything), model.logits(frames[1:]), rtol=1e-5)
    # the ring wraps: transition 0 is reused for a new (s, s') with the classifier unchanged
    newer = goal_like(rng, 1)[0]
    replay.add(int(replay.next_slot[4]), np.zeros(2, np.float32), replay.add_frame(newer), False, None)
    rewards = model.rewards(replay, np.array([0, 1]))
    np.testing.assert_allclose(rewards[0], model.logits(newer[None])[0], rtol=1e-5)
    np.testing.assert_allclose(rewards[1], model.logits(frames[2:3])[0], rtol=1e-5)
    assert not np.isclose(rewards[0], model.logits(frames[1:2])[0])

    # checkpoint round-trip into fresh objects, after the classifier moved on from what was cached
    cached = model.rewards(replay, everything).copy()
    model.update_classifier(goal_like(rng, 8), replay_like(rng, 8))
    after = model.rewards(replay, everything).copy()
    assert not np.allclose(cached, after)
    restored_model = RewardModel.for_run(tiny(algorithm="raq"), np.random.default_rng(1))
    restored_replay = ReplayBuffer(capacity=5, image_shape=(SIZE, SIZE, 3), action_dim=2)
    # the fresh objects' own cache: computed by the untrained net at version 0 (what the load must invalidate)
    restored_replay.add(0, np.zeros(2, np.float32), 1, False, None)
    restored_model.rewards(restored_replay, np.array([0]))
    restored_model.load_state_dict(model.state_dict())
    restored_replay.load_state_dict(replay.state_dict())
    next_frames = replay.frames[replay.next_slot[everything]]
    np.testing.assert_allclose(restored_model.rewards(restored_replay, everything), after, rtol=1e-5)
    np.testing.assert_allclose(restored_model.logits(next_frames), after, rtol=1e-5)
    # a classifier step after the load still invalidates the cache
    restored_model.update_classifier(goal_like(rng, 8), replay_like(rng, 8))
    np.testing.assert_allclose(
        restored_model.rewards(restored_replay, everything), restored_model.logits(next_frames), rtol=1e-5
    )


def test_frames_since_before_the_first_frame_returns_only_written_frames() -> None:
    rng = np.random.default_rng(0)
    replay = ReplayBuffer(capacity=10, image_shape=(SIZE, SIZE, 3), action_dim=2)
    frames = replay_like(rng, 3)
    for frame in frames:
        replay.add_frame(frame)
    np.testing.assert_array_equal(replay.frames_since(replay.frames_added - 256), frames)
    np.testing.assert_array_equal(replay.frames_since(-1), frames)
    np.testing.assert_array_equal(replay.frames_since(1), frames[1:])
    more = replay_like(rng, 30)  # past the ring (22 frames): only what is still stored
    for frame in more:
        replay.add_frame(frame)
    np.testing.assert_array_equal(replay.frames_since(-5), more[-replay.frame_capacity :])


# ---------------------------------------------------------------------------------------------- queries
def _images(count: int) -> list[np.ndarray]:
    return [np.full((SIZE, SIZE, 3), i, dtype=np.uint8) for i in range(count)]


def test_argmax_query_picks_the_best_since_the_last_query_and_never_repeats() -> None:
    selector = QuerySelector("argmax", capacity=3)
    images = _images(6)
    rendered: list[int] = []

    def render_of(i: int):  # the display render taken when the observation is made
        def render() -> np.ndarray:
            rendered.append(i)
            return np.full((32, 32, 3), i, dtype=np.uint8)

        return render

    scores = [0.1, 2.5, 0.7, -1.0, 1.2]
    for i, score in enumerate(scores):
        selector.offer(score, images[i], render_of(i), env_step=i, info={"i": i}, success=float(i == 1))
    assert 3 not in rendered  # only kept candidates are rendered
    best = selector.select()
    assert best is not None and best.env_step == 1 and best.score == 2.5
    assert best.display[0, 0, 0] == 1 and best.info == {"i": 1} and best.success == 1.0
    assert selector.select() is None  # candidates are those since the last query
    # the same observation again, even with a higher score, is never asked again
    assert not selector.offer(9.0, images[1].copy(), render_of(1), env_step=10)
    selector.offer(0.3, images[5], render_of(5), env_step=11)
    second = selector.select()
    assert second is not None and second.env_step == 11
    # re-scoring with the current classifier changes the choice
    selector.offer(1.0, images[3], render_of(3), env_step=12)
    selector.offer(0.5, images[4], render_of(4), env_step=13)
    selector.rescore(lambda batch: batch[:, 0, 0, 0].astype(np.float32))  # image 4 now scores higher
    third = selector.select()
    assert third is not None and third.env_step == 13


def test_entropy_strategy_picks_the_least_certain() -> None:
    selector = QuerySelector("entropy", capacity=8)
    images = _images(4)
    for i, score in enumerate([3.0, -0.2, 0.9, -4.0]):
        selector.offer(score, images[i], lambda: np.zeros((8, 8, 3), np.uint8), env_step=i)
    chosen = selector.select()
    assert chosen is not None and chosen.env_step == 1


def test_selector_state_round_trips() -> None:
    selector = QuerySelector("argmax", capacity=4)
    images = _images(3)
    for i in range(3):
        selector.offer(float(i), images[i], lambda: np.ones((8, 8, 3), np.uint8), env_step=i, info={"x": [1, 2]})
    selector.select()
    restored = QuerySelector("argmax", capacity=4)
    restored.load_state_dict(selector.state_dict())
    assert restored.asked == selector.asked
    assert not restored.offer(5.0, images[2], lambda: np.ones((8, 8, 3), np.uint8), env_step=9)


def test_precision_auto_resolves_to_what_this_machine_runs_faster() -> None:
    assert resolve_precision("fp32") == "fp32" and resolve_precision("bf16", "cuda") == "bf16"
    chosen = resolve_precision("auto")
    assert chosen in ("fp32", "bf16")
    fp32, bf16 = _matmul_seconds(torch.float32), _matmul_seconds(torch.bfloat16)
    if bf16 * 3 < fp32:  # clearly faster in bf16 (AVX512-BF16 / AMX)
        assert chosen == "bf16"
    if fp32 * 3 < bf16:  # bf16 emulated (AVX2 only)
        assert chosen == "fp32"
    device = torch.device("cpu")
    assert input_dtype("auto", device) == (torch.bfloat16 if chosen == "bf16" else torch.float32)
    with precision_autocast("auto", device):
        out = torch.nn.Linear(8, 8)(torch.randn(2, 8))
    assert out.dtype == (torch.bfloat16 if chosen == "bf16" else torch.float32)
    with pytest.raises(ValueError, match="unknown precision"):
        resolve_precision("fp16")


def test_resolving_precision_auto_leaves_the_seeded_random_stream_as_it_was() -> None:
    """A run seeds torch and then builds its networks; measuring which precision is faster in between must not
    draw from the seeded stream, or a seed's initial weights would depend on the precision probe."""
    torch.manual_seed(0)
    expected = torch.randn(4)
    torch.manual_seed(0)
    resolve_precision.__wrapped__("auto")  # measure again (not the cached answer)
    assert torch.equal(torch.randn(4), expected)


def test_a_rollout_gif_holds_every_frame_in_order_close_to_its_colours() -> None:
    rng = np.random.default_rng(0)
    base = rng.integers(0, 256, size=(32, 3), dtype=np.uint8)  # a scene of few colours, as a render is
    frames = [base[rng.integers(0, 32, size=(64, 64))] for _ in range(12)]
    frames[5][:8, :8] = (255, 0, 0)  # a small detail in one frame survives the palette
    gif = Image.open(io.BytesIO(encode_gif(frames, frame_ms=80)))
    assert gif.n_frames == 12 and gif.info["duration"] == 80
    for index, frame in enumerate(frames):
        gif.seek(index)
        decoded = np.asarray(gif.convert("RGB"), dtype=np.int16)
        assert np.abs(decoded - frame).mean() < 2.0, index
    gif.seek(5)
    assert np.abs(np.asarray(gif.convert("RGB"), dtype=np.int16)[:8, :8] - (255, 0, 0)).max() <= 8


def test_schedule_credit_is_zero_for_a_step_at_the_goal_and_a_half_for_a_ramp() -> None:
    """bench/classifier_schedule.py's measure of how much of f_psi's rise comes before success."""
    from bench.classifier_schedule import credit

    steps = np.tile(np.arange(10), 2)  # two episodes of 10 steps, success from step 8 on
    success = (steps >= 8).astype(np.float32)
    step_at_goal = np.where(success > 0, 5.0, -1.0)
    assert credit(step_at_goal, steps, success, random_mean=-1.0) == pytest.approx(0.0)
    ramp = steps.astype(np.float64)  # rises by 1 per step: 0 at the start, 8.5 on the success states
    assert credit(ramp, steps, success, random_mean=0.0) == pytest.approx(3.5 / 8.5)


def test_the_method_comparison_averages_seeds_where_all_evaluated_and_counts_who_reached_90(tmp_path: Path) -> None:
    """bench/compare.py --by-method: one mean curve with its min-max spread per method, cut at the shortest seed
    and at --until, and a table row per method in the methods' one list order."""
    from bench.compare import by_method

    def run(name: str, rates: list[float], queries: int = 0) -> Path:
        folder = tmp_path / name
        folder.mkdir()
        rows = "".join(f"{1000 * (i + 1)},{rate}\n" for i, rate in enumerate(rates))
        (folder / "curve.csv").write_text("step,eval/success_rate\n" + rows)
        summary = {"run": name, "queries_asked": queries, "queries_yes": queries // 2}
        (folder / "summary.json").write_text(json.dumps(summary))
        return folder

    runs = [
        run("pusher-sparse-seed0", [0.0, 0.2, 0.4]),
        run("pusher-vice_raq-seed0", [0.0, 0.6, 1.0, 1.0], queries=4),
        run("pusher-vice_raq-seed1", [0.2, 0.4, 0.8, 0.9, 1.0], queries=2),
    ]
    lines = by_method(runs, tmp_path / "methods.png", "pusher", until=4000)
    assert [line.split(" | ")[0] for line in lines[2:]] == ["| vice_raq", "| sparse"]  # ALGORITHMS' order
    vice_raq = lines[2].split(" | ")
    assert vice_raq[1:5] == ["2", "4,000", "2 of 2", "3,000, 4,000"]  # to 4,000: both seeds evaluated there
    assert vice_raq[5] == f"{(0.1 + 0.5 + 0.9 + 0.95) / 4:.0%}" and vice_raq[7] == "4 (2), 2 (1) |"
    assert lines[3].split(" | ")[2:4] == ["3,000", "0 of 1"] and lines[3].endswith("| - |")
    with Image.open(tmp_path / "methods.png") as image:
        assert image.size == (900, 500)
    assert by_method([*runs, run("pusher-vice-seed0", [])], tmp_path / "m.png", "pusher")[3].startswith(
        "| vice | 1 | no evaluation every seed reached"
    )  # a run stopped before its first evaluation: a row that says so
    with pytest.raises(SystemExit, match="cannot tell the method"):
        by_method([run("door-seed0", [0.0])], tmp_path / "x.png", "door")
