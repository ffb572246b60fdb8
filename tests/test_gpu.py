"""The GPU path where CUDA exists: the SAC update and the classifier step captured as CUDA graphs, replayed with
no host sync (torch.cuda.set_sync_debug_mode("error")), learning as the eager functions do. Where there is no
CUDA device these tests are deselected and listed as not run at the end of the session (tests/conftest.py)."""

import numpy as np
import pytest
import torch

from contract.algorithms import ALGORITHM_SPECS
from contract.config import TrainConfig
from learner.replay import ReplayBuffer
from learner.reward import RewardModel
from learner.sac import SACAgent
from learner.updates import GRAPH_WARMUP_CALLS, DeviceUpdates

pytestmark = pytest.mark.gpu
SIZE = 48


def pipeline(
    algorithm: str, precision: str = "fp32", compiled: bool = False
) -> tuple[DeviceUpdates, ReplayBuffer, SACAgent]:
    rng = np.random.default_rng(0)
    torch.manual_seed(0)
    config = TrainConfig(
        device="cuda", precision=precision, algorithm=algorithm, replay_capacity=2000, compile_updates=compiled
    )  # fmt: skip
    agent = SACAgent.for_run(config, action_dim=3)
    replay = ReplayBuffer(config.replay_capacity, (SIZE, SIZE, 3), 3)
    slot = replay.add_frame(rng.integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8))
    for _ in range(500):
        next_slot = replay.add_frame(rng.integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8))
        replay.add(slot, rng.uniform(-1, 1, 3).astype(np.float32), next_slot, False, 0.0)
        slot = next_slot
    spec = ALGORITHM_SPECS[algorithm]
    model = RewardModel.for_run(config, rng) if spec.classifier else None
    if model is not None:
        model.goals = rng.integers(0, 256, (10, SIZE, SIZE, 3), dtype=np.uint8)
    updates = DeviceUpdates(config, agent=agent, replay=replay, reward_model=model, spec=spec, rng=rng)
    return updates, replay, agent


@pytest.mark.parametrize(
    ("algorithm", "precision", "compiled"),
    [("vice_raq", "fp32", False), ("vice_raq", "bf16", False), ("sparse", "fp32", False), ("sparse", "bf16", False),
     ("vice_raq", "bf16", True)],
)  # fmt: skip
def test_updates_replay_as_cuda_graphs_without_a_host_sync(algorithm: str, precision: str, compiled: bool) -> None:
    updates, replay, agent = pipeline(algorithm, precision, compiled)
    for _ in range(GRAPH_WARMUP_CALLS + 1):
        updates.sac_update()
        if updates.reward_model is not None:
            updates.classifier_step(accuracy=False)
    assert updates.sac_graph.graph is not None and updates.sac_graph.failure is None
    if updates.reward_model is not None:
        assert updates.classifier_graph.graph is not None and updates.classifier_graph.failure is None
    updates.take_metrics()
    before = [p.detach().clone() for p in agent.actor.parameters()]
    torch.cuda.synchronize()
    torch.cuda.set_sync_debug_mode("error")
    try:
        for _ in range(20):
            updates.sac_update()
    finally:
        torch.cuda.set_sync_debug_mode(0)
    metrics = updates.take_metrics()
    assert all(np.isfinite(value) for value in metrics.values()) and "critic/loss" in metrics
    assert any(not torch.equal(a, p) for a, p in zip(before, agent.actor.parameters(), strict=True))


def test_a_captured_sample_sees_the_buffer_grow() -> None:
    updates, replay, _ = pipeline("sparse")
    updates.sac_update()
    graph = torch.cuda.CUDAGraph()
    with torch.cuda.graph(graph):
        indices = updates.replay.sample_indices(4096)
    graph.replay()
    assert indices.max().item() < 500
    slot = replay.add_frame(np.zeros((SIZE, SIZE, 3), dtype=np.uint8))
    for _ in range(1000):
        replay.add(slot, np.zeros(3, dtype=np.float32), slot, False, 0.0)
    updates.replay.sync()
    graph.replay()
    assert 500 <= indices.max().item() < 1500
