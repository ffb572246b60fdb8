"""Where a run's SAC updates and classifier steps get their batches: the host or the training device.

HostUpdates (the CPU path): numpy replay sampling and random shift, rewards f_psi(s') from the replay's
    per-classifier-version cache, one SAC step; metrics read per update.
DeviceUpdates (the GPU path): a DeviceReplay copy of the replay on the device; sample, shift, rewards f_psi(s') of
    the batch (computed in the update, so there is no cache to keep exact) and the SAC step run as one function
    without a host sync, captured as one CUDA graph on a GPU and replayed for each update; the classifier's
    steps likewise. Metrics stay on the device, summed, and are read when the loop records them (`log_every`).
Both give the same update (Alg. 2 lines 13-16) from the same distributions; they draw from different generators.
"""

from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from contract.algorithms import AlgorithmSpec
from contract.config import TrainConfig
from learner.device_replay import DeviceReplay
from learner.replay import ReplayBuffer, shift_pad
from learner.reward import Policy, RewardModel
from learner.sac import SACAgent

GRAPH_WARMUP_CALLS = 3
"""Eager calls on a side stream before a CUDA graph is captured (the allocator and cuDNN settle first)."""


class MetricSums:
    """Per-name sums of update metrics (floats, or 0-d device tensors summed on the device) and their count."""

    def __init__(self) -> None:
        self.sums: dict[str, Any] = {}
        self.count = 0

    def add(self, metrics: dict[str, Any]) -> None:
        if not self.sums:
            self.sums = {
                name: value.float().clone() if torch.is_tensor(value) else value for name, value in metrics.items()
            }
        elif all(torch.is_tensor(value) for value in self.sums.values()):
            torch._foreach_add_(list(self.sums.values()), [metrics[name] for name in self.sums])
        else:
            for name, value in metrics.items():
                self.sums[name] += value
        self.count += 1

    def take(self) -> dict[str, float]:
        """The means since the last take (one host read for device tensors), and a fresh start."""
        names = list(self.sums)
        values = [self.sums[name] for name in names]
        if values and torch.is_tensor(values[0]):
            values = torch.stack([value.float() for value in values]).tolist()
        means = {name: float(value) / max(self.count, 1) for name, value in zip(names, values, strict=True)}
        self.sums, self.count = {}, 0
        return means


class GraphedCall:
    """fn() as a CUDA graph: the first GRAPH_WARMUP_CALLS calls run eagerly on a side stream, the next captures
    fn into a graph and every call from then on replays it. Each call runs fn's work exactly once (capture records
    without running, so the capturing call replays too); the returned tensors are the graph's static outputs,
    overwritten by the next call. Off CUDA, or after a failed capture (`failure` says why), fn() runs eagerly."""

    def __init__(self, fn: Callable[[], Any], device: torch.device, enabled: bool = True) -> None:
        self.fn = fn
        self.device = device
        self.enabled = enabled
        self.calls = 0
        self.graph: torch.cuda.CUDAGraph | None = None
        self.output: Any = None
        self.failure: str | None = None
        self.failure_reported = False

    @property
    def eager(self) -> bool:
        return not self.enabled or self.device.type != "cuda" or self.failure is not None

    def __call__(self) -> Any:
        if self.eager:
            return self.fn()
        if self.graph is None and self.calls < GRAPH_WARMUP_CALLS:
            self.calls += 1
            side = torch.cuda.Stream(self.device)
            side.wait_stream(torch.cuda.current_stream(self.device))
            with torch.cuda.stream(side):
                output = self.fn()
            torch.cuda.current_stream(self.device).wait_stream(side)
            return output
        if self.graph is None:
            graph = torch.cuda.CUDAGraph()
            try:
                with torch.cuda.graph(graph, capture_error_mode="thread_local"):
                    self.output = self.fn()
            except RuntimeError as error:  # the work is still right eagerly; say why it is slower
                self.failure = f"{type(error).__name__}: {str(error).splitlines()[0]}"
                return self.fn()
            self.graph = graph
        self.graph.replay()
        return self.output


def no_answer_count(config: TrainConfig) -> int:
    """Negatives per classifier step drawn from the observations answered no (replay-negative methods)."""
    return round(config.no_answer_share * config.classifier_batch_size)


class HostUpdates:
    """The CPU path: numpy batches, cached rewards, metrics read per update."""

    def __init__(
        self, config: TrainConfig, *, agent: SACAgent, replay: ReplayBuffer, reward_model: RewardModel | None,
        spec: AlgorithmSpec, rng: np.random.Generator,
    ) -> None:  # fmt: skip
        self.config, self.agent, self.replay, self.reward_model, self.spec, self.rng = (
            config, agent, replay, reward_model, spec, rng
        )  # fmt: skip
        self.pad = shift_pad(config.image_size) if config.augmentation == "random_shift" else 0
        self.metrics = MetricSums()

    def describe(self) -> str:
        return "replay sampled on the host (numpy), rewards f_psi(s') cached per classifier version"

    def sac_update(self) -> None:
        batch = self.replay.sample(self.rng, self.config.batch_size, self.pad, self.config.person_share)
        rewards = self._rewards(batch.indices)
        metrics = self.agent.update_from_arrays(batch.obs, batch.action, rewards, batch.next_obs, batch.not_done)
        metrics["reward/batch_mean"] = float(rewards.mean())
        self.metrics.add(metrics)

    def _rewards(self, indices: np.ndarray) -> np.ndarray:
        """Alg. 2 line 15, with the current classifier: r = f_psi(s'); without one, the env's r_env(s')."""
        if self.reward_model is None:
            return self.replay.env_reward[indices].astype(np.float32)  # (reported at every step, or the run fails)
        return self.reward_model.rewards(self.replay, indices)

    def classifier_step(self, *, accuracy: bool, publish: bool = True) -> dict[str, float]:
        """One classifier step (Alg. 2 lines 9-11) on the method's positives and negatives, published at once
        unless told not to; its metrics."""
        policy = self.agent.policy if self.spec.airl else None
        return self.classifier_step_with(self.rng, policy, accuracy=accuracy, publish=publish)

    def classifier_step_with(
        self, rng: np.random.Generator, policy: Policy | None, *, accuracy: bool, publish: bool
    ) -> dict[str, float]:
        """A classifier step drawing from `rng` (batches, mixup) with `policy` as the AIRL form's pi."""
        model = self.reward_model
        assert model is not None
        positives = model.sample_positives(self.config.classifier_batch_size, rng)
        return model.update_classifier(
            positives, self.negatives(rng), policy, accuracy=accuracy, rng=rng, publish=publish
        )

    def negatives(self, rng: np.random.Generator | None = None) -> np.ndarray:
        """A classifier step's negatives: uniform replay samples (VICE methods; the first no_answer_share of them
        from the observations answered no, once there is one), or the pool (raq, naive)."""
        model, size, rng = self.reward_model, self.config.classifier_batch_size, rng or self.rng
        assert model is not None
        if self.spec.negatives == "pool":
            return model.sample_negatives(size, rng)
        negatives = self.replay.sample_next_frames(rng, size)
        answered = no_answer_count(self.config)
        if answered and len(model.answered_negatives):
            picks = rng.integers(0, len(model.answered_negatives), size=answered)
            negatives[:answered] = model.answered_negatives[picks]
        return negatives

    def take_metrics(self) -> dict[str, float]:
        return self.metrics.take()

    def take_notes(self) -> list[str]:
        """What the run's events should say about this path since the last call (nothing, on the host)."""
        return []


class DeviceExamples:
    """A growing set of uint8 images (positives, or the raq pool of negatives) on the device, sampled there; its
    storage is kept (room for `spare` more) so that a captured sample stays valid as answers add to it."""

    def __init__(self, device: torch.device, spare: int) -> None:
        self.device, self.spare = device, spare
        self.images: torch.Tensor | None = None
        self.count = torch.zeros((), dtype=torch.float32, device=device)
        self.last_index = torch.zeros((), dtype=torch.int64, device=device)
        self.synced = 0

    def sync(self, images: np.ndarray) -> bool:
        """Bring the device copy up to `images` (which only grows); True when its storage had to be replaced."""
        replaced = False
        if self.images is None or len(images) > len(self.images):
            self.images = torch.zeros((len(images) + self.spare, *images.shape[1:]), dtype=torch.uint8,
                                      device=self.device)  # fmt: skip
            self.synced, replaced = 0, True
        if len(images) > self.synced:
            self.images[self.synced : len(images)] = torch.from_numpy(images[self.synced :]).to(self.device)
            self.synced = len(images)
            self.count.fill_(float(len(images)))
            self.last_index.fill_(max(len(images) - 1, 0))
        return replaced

    def sample(self, count: int) -> torch.Tensor:
        assert self.images is not None
        uniform = torch.rand(count, device=self.device)
        return self.images[torch.minimum((uniform * self.count).long(), self.last_index)]


class DeviceUpdates:
    """The GPU path: replay, sampling, shift and rewards on the device; the SAC update and the classifier step as
    CUDA graphs (on a CPU device the same functions run eagerly: that is how the tests cover them)."""

    def __init__(
        self, config: TrainConfig, *, agent: SACAgent, replay: ReplayBuffer, reward_model: RewardModel | None,
        spec: AlgorithmSpec, rng: np.random.Generator, graphs: bool = True,
    ) -> None:  # fmt: skip
        self.config, self.agent, self.reward_model, self.spec = config, agent, reward_model, spec
        self.graphs = graphs and agent.device.type == "cuda"
        self.host = HostUpdates(config, agent=agent, replay=replay, reward_model=reward_model, spec=spec, rng=rng)
        self.device = agent.device
        self.replay = DeviceReplay(replay, self.device)
        self.pad = self.host.pad
        self.metrics = MetricSums()
        self.sac_step = self._compiled(self._sac_update_on_device)
        self.classifier_step_fn = self._compiled(self._classifier_step_on_device)
        self.sac_graph = GraphedCall(self.sac_step, self.device, enabled=self.graphs)
        self.classifier_graph = GraphedCall(self.classifier_step_fn, self.device, enabled=self.graphs)
        spare = config.query_budget + 1
        self.positives = DeviceExamples(self.device, spare)
        self.pool_negatives = DeviceExamples(self.device, spare)
        self.no_answers = DeviceExamples(self.device, spare)

    def _compiled(self, fn: Callable[[], Any]) -> Callable[[], Any]:
        """fn through torch.compile when `compile_updates` (its kernels fused; the graph is captured around it)."""
        return torch.compile(fn) if self.config.compile_updates else fn

    def describe(self) -> str:
        graphs = "CUDA graphs" if self.graphs else "eager" + ("" if self.device.type == "cuda" else " (no CUDA)")
        if self.config.compile_updates:
            graphs = f"torch.compile + {graphs}"
        failures = [f"{name}: {g.failure}" for name, g in (("SAC", self.sac_graph), ("f_psi", self.classifier_graph))
                    if g.failure]  # fmt: skip
        note = f"; graph capture failed, eager instead ({'; '.join(failures)})" if failures else ""
        return f"replay sampled on {self.device} with rewards f_psi(s') per batch, updates as {graphs}{note}"

    # ------------------------------------------------------------------ SAC
    def sac_update(self) -> None:
        self.replay.sync()  # (the new frames and transitions of the last batch of env steps, at its first update)
        self.metrics.add(self.sac_graph())

    def _sac_update_on_device(self) -> dict[str, torch.Tensor]:
        """Sample, shift, reward and update, all on the device (Alg. 2 lines 13-16)."""
        batch = self.replay.sample(self.config.batch_size, self.pad, self.config.person_share)
        if self.reward_model is None:
            reward = batch["env_reward"]
        else:  # r = f_psi(s') of the un-shifted s', as the host path's cache computes it
            reward = self.reward_model.rewards_on_device(batch["next_obs_unshifted"])
        agent = self.agent
        metrics = agent.update_tensors(
            agent.images(batch["obs"]), batch["action"], reward, agent.images(batch["next_obs"]), batch["not_done"]
        )
        metrics["reward/batch_mean"] = reward.mean()
        return metrics

    # ------------------------------------------------------------------ f_psi
    def classifier_step(self, *, accuracy: bool, publish: bool = True) -> dict[str, float]:
        """As HostUpdates.classifier_step; the step whose accuracies are read runs on the host's batches (once an
        epoch), every other one on the device as a graph, its loss left unread."""
        model = self.reward_model
        assert model is not None
        if accuracy:
            return self.host.classifier_step(accuracy=True, publish=publish)
        self.replay.sync()
        replaced = self.positives.sync(model.positives)
        if self.spec.negatives == "pool":
            replaced |= self.pool_negatives.sync(model.negatives)
        elif no_answer_count(self.config):
            replaced |= self.no_answers.sync(model.answered_negatives)
        if replaced and self.classifier_graph.graph is not None:  # the old storage is in the graph: capture anew
            self.classifier_graph = GraphedCall(self.classifier_step_fn, self.device, enabled=self.graphs)
        self.classifier_graph()
        if publish:
            model.publish()  # (the version too: a graph replay runs no Python)
        return {}

    def _classifier_step_on_device(self) -> torch.Tensor:
        model, size = self.reward_model, self.config.classifier_batch_size
        assert model is not None
        policy = self.agent.policy if self.spec.airl else None
        return model.step_on_device(self.positives.sample(size), self.negatives_on_device(), policy)

    def negatives_on_device(self) -> torch.Tensor:
        """HostUpdates.negatives on the device (the sets as of the last classifier_step's sync)."""
        size = self.config.classifier_batch_size
        if self.spec.negatives == "pool":
            return self.pool_negatives.sample(size)
        negatives = self.replay.sample_next_frames(size)
        answered = no_answer_count(self.config)
        if not answered:
            return negatives
        use = (self.no_answers.count > 0).view(1, 1, 1, 1)  # (no host read: the graph holds the choice)
        first = torch.where(use, self.no_answers.sample(answered), negatives[:answered])
        return torch.cat([first, negatives[answered:]])

    def take_metrics(self) -> dict[str, float]:
        return self.metrics.take()

    def take_notes(self) -> list[str]:
        """A CUDA graph capture that failed since the last call (its work then runs eagerly, slower)."""
        notes = []
        for name, graph in (("SAC update", self.sac_graph), ("classifier step", self.classifier_graph)):
            if graph.failure and not graph.failure_reported:
                graph.failure_reported = True
                notes.append(f"the {name} could not be captured as a CUDA graph and runs eagerly: {graph.failure}")
        return notes


def make_updates(
    config: TrainConfig, *, agent: SACAgent, replay: ReplayBuffer, reward_model: RewardModel | None,
    spec: AlgorithmSpec, rng: np.random.Generator,
) -> HostUpdates | DeviceUpdates:  # fmt: skip
    """The run's update path: `replay_pipeline`, where auto means the device's on a GPU and the host's on a CPU."""
    on_device = config.replay_pipeline == "device" or (config.replay_pipeline == "auto" and agent.device.type == "cuda")
    kind = DeviceUpdates if on_device else HostUpdates
    return kind(config, agent=agent, replay=replay, reward_model=reward_model, spec=spec, rng=rng)
