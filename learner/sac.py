"""Soft actor-critic from pixels (Haarnoja et al. 2018), with the paper's or a DrQ-style shared encoder.

shared_encoder=False (TrainConfig.paper()): the actor and each Q-function have their own conv net, the target
Q-functions are full copies (conv nets included), as in the paper's softlearning code.
shared_encoder=True: one conv net, trained by the critic loss only; the actor sees detached features, and the
target Q heads read the online encoder's features of s' (DrQ-v2's layout), so the encoder runs once on s and
once on s' per update.
"""

import copy
import math
from contextlib import AbstractContextManager
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from contract.config import NetworkConfig, SACConfig, TrainConfig
from learner.networks import (
    TWIN_MLP_INDICES,
    Actor,
    ConvEncoder,
    Critic,
    SharedEncoder,
    autocast_of,
    dtype_of,
    resolve_precision,
    squashed_gaussian_sample,
    to_float,
    twin_to_ensemble,
)

FP32_ACTING_MAX = 16
"""CPU acting batches up to this size run in fp32 (measured on AMX: fp32 faster at 1-8 images, bf16 at 64)."""


def sample_policy(
    actor: torch.nn.Module, encoder: torch.nn.Module | None, images: torch.Tensor,
    context: AbstractContextManager[Any], deterministic: bool = False, generator: torch.Generator | None = None,
    noise: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
    """(a, log pi(a|s)) of `actor` on float images (through the shared `encoder` when there is one), the networks
    run without gradients inside `context` (autocast, or inference mode), the action drawn from `generator` (or
    with the given N(0, 1) `noise`, one row per image)."""
    with torch.no_grad(), context:
        mean, log_std = actor(encoder(images) if encoder is not None else images)
    return squashed_gaussian_sample(mean, log_std, deterministic, generator, noise)


class SACAgent:
    """Actor, twin critic, target critic, temperature, and their Adam optimizers."""

    def __init__(
        self, sac: SACConfig, networks: NetworkConfig, action_dim: int, *, image_size: int, device: str = "cpu",
        precision: str = "auto",
    ) -> None:  # fmt: skip
        self.config = sac
        self.device = torch.device(device)
        self.precision = resolve_precision(precision, self.device.type)
        self.action_dim = action_dim
        size, filters, hidden, kind = image_size, networks.conv_filters, networks.hidden_dim, networks.encoder
        if networks.shared_encoder:
            self.encoder: SharedEncoder | None = SharedEncoder(size, filters, kind, networks.feature_dim)
            feature_dim = self.encoder.output_dim
            self.actor = Actor(feature_dim, action_dim, hidden, encoder=None)
            self.critic = Critic(feature_dim, action_dim, hidden, encoders=None, layer_norm=networks.critic_layer_norm)
        else:
            self.encoder = None
            feature_dim = ConvEncoder(size, filters, kind).output_dim
            self.actor = Actor(feature_dim, action_dim, hidden, encoder=ConvEncoder(size, filters, kind))
            encoders = (ConvEncoder(size, filters, kind), ConvEncoder(size, filters, kind))
            self.critic = Critic(
                feature_dim, action_dim, hidden, encoders=encoders, layer_norm=networks.critic_layer_norm
            )
        for module in self.modules().values():
            module.to(self.device, memory_format=torch.channels_last)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.log_alpha = torch.tensor(math.log(sac.initial_alpha), device=self.device, requires_grad=True)
        self.target_entropy = float(sac.target_entropy if sac.target_entropy is not None else -action_dim)
        fused = self.device.type in ("cpu", "cuda")
        capturable = self.device.type == "cuda"  # step counts on the device: an update can be a CUDA graph
        critic_params = list(self.critic.parameters())
        if self.encoder is not None:
            critic_params += list(self.encoder.parameters())
        self.critic_opt = torch.optim.Adam(critic_params, lr=sac.critic_lr, fused=fused, capturable=capturable)
        self.actor_opt = torch.optim.Adam(
            self.actor.parameters(), lr=sac.actor_lr, fused=fused, capturable=capturable
        )
        self.alpha_opt = torch.optim.Adam([self.log_alpha], lr=sac.alpha_lr, capturable=capturable)

    @classmethod
    def for_run(cls, config: TrainConfig, action_dim: int) -> "SACAgent":
        """The run's agent: its SAC and network parts, its image size, device and precision."""
        return cls(
            config.sac, config.networks, action_dim, image_size=config.image_size, device=config.device,
            precision=config.precision,
        )  # fmt: skip

    # ------------------------------------------------------------------ helpers
    def modules(self) -> dict[str, torch.nn.Module]:
        modules: dict[str, torch.nn.Module] = {"actor": self.actor, "critic": self.critic}
        if self.encoder is not None:
            modules["encoder"] = self.encoder
        if hasattr(self, "critic_target"):
            modules["critic_target"] = self.critic_target
        return modules

    def images(self, images: np.ndarray) -> torch.Tensor:
        """uint8 NHWC images -> the networks' input (bf16 at once under bf16 precision)."""
        return to_float(images, self.device, dtype_of(self.precision))

    def autocast(self) -> AbstractContextManager[Any]:
        return autocast_of(self.precision, self.device)

    @property
    def alpha(self) -> torch.Tensor:
        return self.log_alpha.detach().exp()

    def _features(self, images: torch.Tensor) -> torch.Tensor:
        """What the actor and critic heads take: shared-encoder features, or the images themselves."""
        return self.encoder(images) if self.encoder is not None else images

    def policy(self, images: torch.Tensor, deterministic: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        """(a, log pi(a|s)) for float images, no gradients (acting, evaluation, VICE's action sampling)."""
        return sample_policy(self.actor, self.encoder, images, self.autocast(), deterministic)

    def policy_copy(self, generator: torch.Generator) -> "PolicyCopy":
        """A copy of pi as it is now, drawing its actions from `generator` (see PolicyCopy)."""
        return PolicyCopy(self, generator)

    def act(self, observation: np.ndarray, deterministic: bool = False) -> np.ndarray:
        """One uint8 HWC observation -> an action in [-1, 1]^dim(A)."""
        return self.act_batch(observation[None], deterministic)[0]

    def act_batch(
        self, observations: np.ndarray, deterministic: bool = False, generator: torch.Generator | None = None,
        noise: torch.Tensor | None = None,
    ) -> np.ndarray:  # fmt: skip
        """uint8 NHWC observations -> one action each, from one forward pass, the noise drawn from `generator`
        (default torch's) or given (`noise`: N(0, 1), one row per observation)."""
        return self.act_with(self.actor, self.encoder, observations, deterministic, generator, noise)

    def act_with(
        self, actor: torch.nn.Module, encoder: torch.nn.Module | None, observations: np.ndarray,
        deterministic: bool, generator: torch.Generator | None, noise: torch.Tensor | None = None,
    ) -> np.ndarray:  # fmt: skip
        """`act_batch` with these networks (the agent's or a PolicyCopy's). On a CPU a batch of at most
        FP32_ACTING_MAX images runs in fp32 whatever the precision: bf16 autocast casts every weight per call,
        which costs more than its faster matmuls save at a few images (1 image: 0.54 ms bf16, 0.30 ms fp32)."""
        if self.device.type == "cpu" and len(observations) <= FP32_ACTING_MAX:
            images = to_float(observations, self.device, torch.float32)
            context: AbstractContextManager[Any] = torch.inference_mode()
        else:
            images, context = self.images(observations), self.autocast()
        action, _ = sample_policy(actor, encoder, images, context, deterministic, generator, noise)
        return action.float().cpu().numpy()

    # ------------------------------------------------------------------ updates
    def update_from_arrays(
        self, obs: np.ndarray, action: np.ndarray, reward: np.ndarray, next_obs: np.ndarray, not_done: np.ndarray
    ) -> dict[str, float]:
        """`update` on a replay batch as numpy arrays (uint8 NHWC images)."""
        device = self.device
        return self.update(
            self.images(obs), torch.from_numpy(action).to(device), torch.from_numpy(reward).to(device),
            self.images(next_obs), torch.from_numpy(not_done).to(device),
        )  # fmt: skip

    def update(
        self, obs: torch.Tensor, action: torch.Tensor, reward: torch.Tensor, next_obs: torch.Tensor,
        not_done: torch.Tensor,
    ) -> dict[str, float]:  # fmt: skip
        """One SAC gradient step on float image batches (already augmented); returns metrics."""
        metrics = self.update_tensors(obs, action, reward, next_obs, not_done)
        return {name: value.item() for name, value in metrics.items()}

    def update_tensors(
        self, obs: torch.Tensor, action: torch.Tensor, reward: torch.Tensor, next_obs: torch.Tensor,
        not_done: torch.Tensor,
    ) -> dict[str, torch.Tensor]:  # fmt: skip
        """`update` with its metrics left as 0-d tensors on the device: no host sync, so it can be a CUDA graph."""
        metrics, actor_inputs = self.update_critic(obs, action, reward, next_obs, not_done)
        metrics.update(self.update_actor_and_alpha(actor_inputs))
        self.update_target()
        return metrics

    def update_critic(
        self, obs: torch.Tensor, action: torch.Tensor, reward: torch.Tensor, next_obs: torch.Tensor,
        not_done: torch.Tensor,
    ) -> tuple[dict[str, torch.Tensor], torch.Tensor]:  # fmt: skip
        """Soft Bellman residual on both Q's; returns metrics and the actor's inputs (detached features or images)."""
        with torch.no_grad(), self.autocast():
            next_inputs = self._features(next_obs)
            mean, log_std = self.actor(next_inputs)
            next_action, next_log_pi = squashed_gaussian_sample(mean, log_std)
            target_q1, target_q2 = self.critic_target(next_inputs, next_action)
        # y = r + gamma (1 - d) (min_j Q'_j(s', a') - alpha log pi(a'|s')),  a' ~ pi(.|s')
        soft_value = torch.min(target_q1, target_q2) - self.alpha * next_log_pi
        target = reward + self.config.discount * not_done * soft_value
        with self.autocast():
            inputs = self._features(obs)
            q1, q2 = self.critic(inputs, action)
        critic_loss = 0.5 * (F.mse_loss(q1, target) + F.mse_loss(q2, target))
        self.critic_opt.zero_grad(set_to_none=True)
        critic_loss.backward()
        self.critic_opt.step()
        metrics = {
            "critic/loss": critic_loss.detach(),
            "critic/q_mean": q1.detach().mean(),
            "critic/target_mean": target.mean(),
        }
        actor_inputs = inputs.detach() if self.encoder is not None else obs
        return metrics, actor_inputs

    def update_actor_and_alpha(self, inputs: torch.Tensor) -> dict[str, torch.Tensor]:
        """Reparameterised policy step on alpha log pi(a|s) - min_j Q_j(s, a), then the temperature step."""
        self.critic.requires_grad_(False)  # the actor loss must not leave gradients on the critic
        try:
            with self.autocast():
                mean, log_std = self.actor(inputs)
                action, log_pi = squashed_gaussian_sample(mean, log_std)
                q1, q2 = self.critic(inputs, action)
            actor_loss = (self.alpha * log_pi - torch.min(q1, q2)).mean()
            self.actor_opt.zero_grad(set_to_none=True)
            actor_loss.backward()
            self.actor_opt.step()
        finally:
            self.critic.requires_grad_(True)
        # J(alpha) = E[-alpha (log pi(a|s) + target entropy)]  (SAC, Haarnoja et al. 2018b, Eq. 18)
        alpha_loss = -(self.log_alpha * (log_pi.detach() + self.target_entropy)).mean()
        self.alpha_opt.zero_grad(set_to_none=True)
        alpha_loss.backward()
        self.alpha_opt.step()
        return {
            "actor/loss": actor_loss.detach(),
            "actor/entropy": -log_pi.detach().mean(),
            "alpha/loss": alpha_loss.detach(),
            "alpha/value": self.alpha,
        }

    @torch.no_grad()
    def update_target(self) -> None:
        """Polyak averaging of the target critic, every step: theta' <- tau theta + (1 - tau) theta'."""
        online = list(self.critic.parameters())
        target = list(self.critic_target.parameters())
        torch._foreach_lerp_(target, online, self.config.tau)

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict[str, Any]:
        state: dict[str, Any] = {name: module.state_dict() for name, module in self.modules().items()}
        state["log_alpha"] = self.log_alpha.detach().clone()
        state["critic_opt"] = self.critic_opt.state_dict()
        state["actor_opt"] = self.actor_opt.state_dict()
        state["alpha_opt"] = self.alpha_opt.state_dict()
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if "q1.0.weight" in state["critic"]:  # written before the twin Q MLPs became one ensemble
            state = {**state, "critic_opt": _ensemble_optimizer_state(state["critic_opt"], state["critic"])}
        for name, module in self.modules().items():
            module.load_state_dict(state[name])
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        self.critic_opt.load_state_dict(state["critic_opt"])
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.alpha_opt.load_state_dict(state["alpha_opt"])


class PolicyCopy:
    """A copy of the actor (and shared encoder) that draws its actions from its own generator, so that it can act
    on one thread while the SAC updates change the originals on another (the loop's acting beside the updates).
    `sync` copies the originals' weights in again; call it while no update runs."""

    def __init__(self, agent: SACAgent, generator: torch.Generator) -> None:
        self.agent, self.generator = agent, generator
        self.actor = copy.deepcopy(agent.actor).requires_grad_(False)
        self.encoder = copy.deepcopy(agent.encoder).requires_grad_(False) if agent.encoder is not None else None
        originals = [agent.actor] + ([agent.encoder] if agent.encoder is not None else [])
        copies = [self.actor] + ([self.encoder] if self.encoder is not None else [])
        self.sources = [t for module in originals for t in (*module.parameters(), *module.buffers())]
        self.targets = [t for module in copies for t in (*module.parameters(), *module.buffers())]

    @torch.no_grad()
    def sync(self) -> None:
        torch._foreach_copy_(self.targets, self.sources)

    def __call__(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(a, log pi(a|s)) for float images, as SACAgent.policy (a `learner.reward.Policy`)."""
        return sample_policy(self.actor, self.encoder, images, self.agent.autocast(), generator=self.generator)

    def act_batch(
        self, observations: np.ndarray, deterministic: bool = False, noise: torch.Tensor | None = None
    ) -> np.ndarray:
        """SACAgent.act_batch of the copy."""
        return self.agent.act_with(self.actor, self.encoder, observations, deterministic, self.generator, noise)


def _ensemble_optimizer_state(optimizer: dict[str, Any], critic: dict[str, torch.Tensor]) -> dict[str, Any]:
    """The critic optimizer's Adam state from before the ensemble layout, for the ensemble's parameters.

    Its parameters were the critic's (own encoders, q1's 6 tensors, q2's 6 tensors, in state-dict order) then
    the shared encoder's; the ensemble keeps that order with q1 and q2 stacked into 3 weights and 3 biases."""
    names = list(critic)
    first_q = names.index("q1.0.weight")
    assert len(optimizer["param_groups"]) == 1, "the critic optimizer has one parameter group"
    group = optimizer["param_groups"][0]
    ids = group["params"]
    moved = {name: optimizer["state"].get(ids[index]) for index, name in enumerate(names)}
    new_states = [moved[name] for name in names[:first_q]]
    for sequential_index in TWIN_MLP_INDICES:
        for kind in ("weight", "bias"):
            one, two = (moved[f"q{q}.{sequential_index}.{kind}"] for q in (1, 2))
            if one is None or two is None:  # Adam has state for both Q's or (before any step) neither
                assert one is two is None
                new_states.append(None)
                continue
            new_states.append(
                {key: one[key] if key == "step" else twin_to_ensemble(kind, one[key], two[key]) for key in one}
            )
    new_states += [optimizer["state"].get(index) for index in ids[len(names) :]]
    new_ids = list(range(len(new_states)))
    return {
        "state": {index: value for index, value in zip(new_ids, new_states, strict=True) if value is not None},
        "param_groups": [{**group, "params": new_ids}],
    }
