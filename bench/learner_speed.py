"""SAC updates per second at batch 256 on 48x48 images: the paper's configuration against the default.

One "update" is what the learner does per environment step after warm-up: sample a batch (with the
default's random shift), compute rewards r = f_psi(s') with the current classifier (cached per classifier
version), one SAC step (critic, actor, alpha, target); the classifier's own steps (10 per 1000 env steps,
each invalidating the reward cache) are amortised in. Environment stepping is not included.

    python bench/learner_speed.py [--updates 300] [--device cpu|cuda] [--threads N]
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from learner.config import TrainConfig  # noqa: E402
from learner.networks import to_float  # noqa: E402
from learner.replay import ReplayBuffer, shift_pad  # noqa: E402
from learner.reward import RewardModel  # noqa: E402
from learner.sac import SACAgent  # noqa: E402


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


def measure(config: TrainConfig, updates: int, transitions: int) -> float:
    """Updates per second, best of two timed blocks after a warm-up."""
    rng = np.random.default_rng(0)
    torch.manual_seed(0)
    agent = SACAgent(config, action_dim=2)
    reward_model = RewardModel(config, rng)
    reward_model.goals = rng.integers(0, 256, size=(10, config.image_size, config.image_size, 3), dtype=np.uint8)
    replay = filled_replay(config, transitions, rng)
    pad = shift_pad(config.image_size) if config.augmentation == "random_shift" else 0
    device = agent.device
    classifier_every = max(1, round(config.epoch_steps / max(config.classifier_steps, 1)))

    def one_update(index: int) -> None:
        if config.classifier_steps and index % classifier_every == 0:  # amortised: classifier_steps per epoch
            positives = reward_model.sample_positives(config.classifier_batch_size)
            negatives = replay.sample_next_frames(rng, config.classifier_batch_size)
            reward_model.update_classifier(positives, negatives, agent.policy, accuracy=False)  # as train.py
        batch = replay.sample(rng, config.batch_size, pad)
        rewards = reward_model.rewards(replay, batch.indices)
        agent.update(
            to_float(batch.obs, device), torch.from_numpy(batch.action).to(device),
            torch.from_numpy(rewards).to(device), to_float(batch.next_obs, device),
            torch.from_numpy(batch.not_done).to(device),
        )  # fmt: skip

    for index in range(10):
        one_update(index)
    best = 0.0
    for _block in range(2):
        if device.type == "cuda":
            torch.cuda.synchronize()
        start = time.perf_counter()
        for index in range(updates):
            one_update(index)
        if device.type == "cuda":
            torch.cuda.synchronize()
        best = max(best, updates / (time.perf_counter() - start))
    return best


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--updates", type=int, default=300, help="updates per timed block (two blocks)")
    parser.add_argument("--transitions", type=int, default=20_000, help="replay size sampled from")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: torch's)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, device {args.device}, {torch.get_num_threads()} threads, batch 256, 48x48")
    precision = "fp32" if args.device != "cpu" else None
    paper = TrainConfig.paper(device=args.device)
    default = TrainConfig(device=args.device, **({"precision": precision} if precision else {}))
    results = {}
    for name, config in (("paper", paper), ("default", default)):
        results[name] = measure(config, args.updates, args.transitions)
        print(
            f"{name:8s} updates/s {results[name]:7.2f}   (shared_encoder={config.shared_encoder}, "
            f"augmentation={config.augmentation}, precision={config.precision})",
            flush=True,
        )
    print(f"ratio default/paper: {results['default'] / results['paper']:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
