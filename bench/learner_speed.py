"""SAC updates per second at batch 256 on 48x48 images: the paper's configuration against the default.

One "update" is what the learner does per environment step after warm-up: sample a batch (with the
default's random shift), compute rewards r = f_psi(s') with the current classifier (cached per classifier
version), one SAC step (critic, actor, alpha, target). The classifier's own steps are amortised in as the
training loop runs them: in a burst before each block of updates, classifier_steps * updates / epoch_steps of
them (the loop: classifier_steps at every epoch_steps-th env step), so every block starts with the whole reward
cache stale and fills it as the loop does (at the default 300 updates over 20,000 transitions, about 65
f_psi evaluations per update; the loop does 50 per update with 50K transitions, 92 with 100K).
Environment stepping is not included.

On a GPU it also measures the device pipeline (`replay_pipeline="device"`, learner/updates.py): replay on the
GPU, sampling, shift and rewards f_psi(s') inside the update, the update and the classifier step replayed as CUDA
graphs, eagerly and as graphs; the graphed updates run under `torch.cuda.set_sync_debug_mode("error")`, so a host
sync inside an update would stop the benchmark.

    python bench/learner_speed.py [--updates 300] [--blocks 2] [--device cpu|cuda [--compile] [--graphs-only]]
                                  [--threads N]
"""

import argparse
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from contract.algorithms import ALGORITHM_SPECS  # noqa: E402
from contract.config import TrainConfig  # noqa: E402
from learner.networks import resolve_precision  # noqa: E402
from learner.replay import ReplayBuffer, shift_pad  # noqa: E402
from learner.reward import RewardModel  # noqa: E402
from learner.sac import SACAgent  # noqa: E402
from learner.updates import GRAPH_WARMUP_CALLS, DeviceUpdates  # noqa: E402


def filled_replay(config: TrainConfig, transitions: int, rng: np.random.Generator) -> ReplayBuffer:
    """A buffer of smooth random images (cheap to make, same cost to learn from as rendered ones)."""
    size = config.image_size
    replay = ReplayBuffer(max(transitions, 1000), (size, size, 3), 2)
    base = rng.integers(0, 256, size=(64, size, size, 3), dtype=np.uint8)
    slot = replay.add_frame(base[0])
    for index in range(transitions):
        next_slot = replay.add_frame(base[(index + 1) % 64])
        replay.add(slot, rng.uniform(-1, 1, 2).astype(np.float32), next_slot, False, 0.0)
        slot = next_slot
    return replay


def matmul_gflops(dtype: torch.dtype = torch.bfloat16, seconds: float = 2.0) -> float:
    """Matmul throughput of this machine now in `dtype` (357 GFLOP/s bf16 peak on an idle 2-core
    VM with AVX512-BF16; a CPU with AVX2 only emulates bf16 at about 1 GFLOP/s): printed beside updates/s so that a
    slow moment of a shared machine, or a machine of another kind, shows as such."""
    a, b = torch.randn(1024, 1024).to(dtype), torch.randn(1024, 1024).to(dtype)
    torch.mm(a, b)
    count, start = 0, time.perf_counter()
    while count < 2 or time.perf_counter() - start < seconds:
        torch.mm(a, b)
        count += 1
    return 2 * 1024**3 * count / (time.perf_counter() - start) / 1e9


def machine_line() -> str:
    """This machine's fp32 and bf16 matmul GFLOP/s now, and the precision "auto" picks on it."""
    fp32, bf16 = matmul_gflops(torch.float32), matmul_gflops(torch.bfloat16)
    return (
        f"this machine now: {fp32:.0f} GFLOP/s fp32, {bf16:.0f} GFLOP/s bf16 matmul (1024x1024); "
        f"precision auto -> {resolve_precision('auto')}"
    )


def learner_parts(
    config: TrainConfig, transitions: int
) -> tuple[np.random.Generator, SACAgent, RewardModel, ReplayBuffer]:
    """Seeded generator, agent, f_psi with 10 random goal images, and a filled replay buffer."""
    rng = np.random.default_rng(0)
    torch.manual_seed(0)
    agent = SACAgent.for_run(config, action_dim=2)
    reward_model = RewardModel.for_run(config, rng)
    reward_model.goals = rng.integers(0, 256, size=(10, config.image_size, config.image_size, 3), dtype=np.uint8)
    return rng, agent, reward_model, filled_replay(config, transitions, rng)


def measure(config: TrainConfig, updates: int, transitions: int, blocks: int) -> tuple[float, dict[str, float]]:
    """(updates per second, milliseconds per update by part) of the best of `blocks` timed blocks."""
    rng, agent, reward_model, replay = learner_parts(config, transitions)
    pad = shift_pad(config.image_size) if config.augmentation == "random_shift" else 0
    device = agent.device
    updates_per_epoch = config.epoch_steps * config.updates_per_step
    classifier_steps_per_block = (
        max(1, round(config.classifier_steps * updates / updates_per_epoch)) if config.classifier_steps else 0
    )
    parts: dict[str, float] = defaultdict(float)

    def timed(part: str, start: float) -> float:
        """Adds the time since `start` to `part` (on a GPU not at all: a sync per part would cost overlap)."""
        if device.type != "cpu":
            return start
        now = time.perf_counter()
        parts[part] += now - start
        return now

    def classifier_burst(steps: int) -> None:
        start = time.perf_counter()
        for index in range(steps):  # as train.py's _train_classifier: accuracies on the last step only
            positives = reward_model.sample_positives(config.classifier_batch_size)
            negatives = replay.sample_next_frames(rng, config.classifier_batch_size)
            reward_model.update_classifier(positives, negatives, agent.policy, accuracy=index == steps - 1)
        timed("classifier steps", start)

    def one_update() -> None:
        start = time.perf_counter()
        batch = replay.sample(rng, config.batch_size, pad)
        start = timed("sample + shift", start)
        rewards = reward_model.rewards(replay, batch.indices)
        start = timed("rewards f_psi(s')", start)
        agent.update_from_arrays(batch.obs, batch.action, rewards, batch.next_obs, batch.not_done)
        timed("SAC step", start)

    classifier_burst(1)
    for _ in range(10):
        one_update()
    best, best_parts = 0.0, {}
    for _block in range(blocks):
        parts.clear()
        start = time.perf_counter()
        classifier_burst(classifier_steps_per_block)
        for _ in range(updates):
            one_update()
        if device.type == "cuda":
            torch.cuda.synchronize()
        rate = updates / (time.perf_counter() - start)
        if rate > best:
            best, best_parts = rate, {part: 1000 * total / updates for part, total in parts.items()}
    return best, best_parts


def measure_device_pipeline(
    config: TrainConfig, updates: int, transitions: int, blocks: int, graphs: bool
) -> tuple[float, str]:
    """(updates per second, how it ran) of the device pipeline: as the loop does it, a classifier burst (all but
    its last step as graphs) then `updates` SAC updates; `graphs=False` runs the same functions eagerly."""
    rng, agent, reward_model, replay = learner_parts(config, transitions)
    pipeline = DeviceUpdates(
        config, agent=agent, replay=replay, reward_model=reward_model, spec=ALGORITHM_SPECS[config.algorithm], rng=rng,
        graphs=graphs,
    )  # fmt: skip
    per_block = max(1, round(config.classifier_steps * updates / (config.epoch_steps * config.updates_per_step)))
    for _ in range(GRAPH_WARMUP_CALLS + 2):  # warm-up, capture and a first replay of both graphs
        pipeline.classifier_step(accuracy=False)
        pipeline.sac_update()
    pipeline.take_metrics()
    torch.cuda.synchronize()
    best = 0.0
    for _block in range(blocks):
        start = time.perf_counter()
        for index in range(per_block):
            pipeline.classifier_step(accuracy=index == per_block - 1)
        torch.cuda.set_sync_debug_mode("error" if graphs else 0)  # a host sync in an update raises
        try:
            for _ in range(updates):
                pipeline.sac_update()
        finally:
            torch.cuda.set_sync_debug_mode(0)
        torch.cuda.synchronize()
        best = max(best, updates / (time.perf_counter() - start))
    metrics = pipeline.take_metrics()
    assert all(np.isfinite(value) for value in metrics.values()), metrics
    return best, pipeline.describe()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--updates", type=int, default=300, help="updates per timed block (see --blocks)")
    parser.add_argument("--transitions", type=int, default=20_000, help="replay size sampled from")
    parser.add_argument("--blocks", type=int, default=2, help="timed blocks per configuration (the best counts)")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--compile", action="store_true", help="on a GPU also measure compile_updates=True")
    parser.add_argument(
        "--graphs-only", action="store_true", help="on a GPU measure only the device pipeline's CUDA graphs"
    )
    parser.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: torch's)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, device {args.device}, {torch.get_num_threads()} threads, batch 256, 48x48")
    print(machine_line(), flush=True)
    precision = "fp32" if args.device != "cpu" else None
    paper = TrainConfig.paper(device=args.device)
    default = TrainConfig(device=args.device, **({"precision": precision} if precision else {}))
    results = {}
    graphs_only = args.graphs_only and args.device.startswith("cuda")
    host_configs = () if graphs_only else (("paper", paper), ("default", default))
    for name, config in host_configs:
        results[name], parts = measure(config, args.updates, args.transitions, args.blocks)
        print(
            f"{name:8s} updates/s {results[name]:7.2f}   (shared_encoder={config.shared_encoder}, "
            f"augmentation={config.augmentation}, precision={config.precision}"
            f" -> {resolve_precision(config.precision, torch.device(args.device).type)})",
            flush=True,
        )
        if parts:
            print("         ms per update: " + ", ".join(f"{part} {ms:.1f}" for part, ms in parts.items()), flush=True)
    if results:
        print(f"ratio default/paper: {results['default'] / results['paper']:.2f}x")
    if args.device.startswith("cuda"):
        variants = [
            (precision, graphs, False)
            for precision in ("fp32", "bf16")
            for graphs in ((True,) if graphs_only else (False, True))
        ]
        if args.compile:
            variants.append(("bf16", True, True))
        for precision, graphs, compiled in variants:
            config = TrainConfig(
                device=args.device, precision=precision, replay_pipeline="device", compile_updates=compiled
            )  # fmt: skip
            started = time.perf_counter()
            rate, how = measure_device_pipeline(config, args.updates, args.transitions, args.blocks, graphs)
            label = f"device pipeline, {precision}, {'CUDA graphs' if graphs else 'eager'}"
            label += ", torch.compile" if compiled else ""
            seconds = time.perf_counter() - started
            print(f"{label:55s} updates/s {rate:7.1f}   ({how}; {seconds:.0f} s in all)", flush=True)
    print(machine_line())
    return 0


if __name__ == "__main__":
    sys.exit(main())
