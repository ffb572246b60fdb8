"""The classifier schedule against the shape of f_psi, offline: a fresh f_psi per setting, trained on a run's replay.

    python bench/classifier_schedule.py bench/out/door-vice_raq-seed0/data/checkpoints/run-1/checkpoint.pt

A sweep of the classifier's steps per epoch ({5, 10, 100}) and learning rate ({1e-4, 3e-4}) on the door (the
paper found the door learned best with few steps) costs hours as learning runs; this asks the cheaper question the
sweep rests on: which settings give f_psi a slope that SAC can
climb along the path to success (approach, hook, pull), and which only a step at the goal?

For each setting it trains a fresh f_psi as the run would have, epoch by epoch (the first epoch untrained): epoch
k's negatives uniform over the replay's first k x epoch_steps transitions, the run's goal images and "yes" answers
as positives, the run's mixup, and the AIRL term with the checkpoint's policy (the run's last policy stands in for
the policy of each epoch: the one approximation). Then it plays the scripted controller (which succeeds) and
uniformly random actions (`bench/reward_shape.py`'s episodes) and prints per setting: f_psi by tenth of the
scripted episodes, on random states and on the goal images, the rank correlation of f_psi with closeness to
success on the scripted states, and `credit`: the share of the scripted path's rise in f_psi (random states to
success states) that is reached before success, averaged over the path's states before their first success. A
reward that is a step at the goal has credit near 0; one that rises steadily along the path, about 0.4-0.5. On the
door, `--landscape` also prints each setting's f_psi with the door shut over the hand's (y, z) (see
`bench/reward_shape.py`): where the reward draws the hand before anything has opened.
"""

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.reward_shape import door_landscape, load_run, play, rank_correlation  # noqa: E402
from contract.config import TrainConfig  # noqa: E402
from contract.envs import make_env  # noqa: E402
from learner.replay import ReplayBuffer  # noqa: E402
from learner.reward import RewardModel  # noqa: E402
from learner.sac import SACAgent  # noqa: E402
from learner.updates import no_answer_count  # noqa: E402

STEPS_PER_EPOCH = (5, 10, 100)
LEARNING_RATES = (1e-4, 3e-4)


def train(
    config: TrainConfig, replay: ReplayBuffer, positives: np.ndarray, agent: SACAgent, epochs: int, seed: int
) -> RewardModel:
    """A fresh f_psi trained for `epochs` epochs of `config.classifier_steps` steps on the replay as it grew. With
    `no_answer_share` > 0, every `query_every` transitions the observation f_psi rates highest since the last query
    is asked about (answered from the replay's success flag), and the "no" answers make that share of each step's
    negatives, as the learner does."""
    torch.manual_seed(seed)
    model = RewardModel.for_run(config, np.random.default_rng(seed))
    model.goals = positives
    rng = np.random.default_rng(seed + 1)
    asked = 0
    for epoch in range(1, epochs):  # no training during the first epoch (as in the paper's code)
        seen = min(len(replay), epoch * config.epoch_steps)
        while config.no_answer_share > 0 and asked + config.query_every <= seen:
            since = np.arange(asked, asked + config.query_every)
            best = since[int(np.argmax(model.logits(replay.frames[replay.next_slot[since]])))]
            image = replay.frames[replay.next_slot[best]]
            (model.add_positive if replay.env_reward[best] > 0 else model.add_negative)(image)
            asked += config.query_every
        answered = no_answer_count(config) if len(model.answered_negatives) else 0
        for _ in range(config.classifier_steps):
            picks = rng.integers(0, seen, size=config.classifier_batch_size)
            negatives = replay.frames[replay.next_slot[picks]]
            negatives[:answered] = model.answered_negatives[rng.integers(0, len(model.answered_negatives), answered)]
            model.update_classifier(
                model.sample_positives(config.classifier_batch_size), negatives, agent.policy, accuracy=False
            )  # fmt: skip
    return model


def credit(logits: np.ndarray, steps: np.ndarray, success: np.ndarray, random_mean: float) -> float:
    """Mean over the scripted path's states before each episode's first success of
    (f_psi - mean f_psi on random states) / (mean f_psi on success states - mean f_psi on random states)."""
    starts = np.flatnonzero(steps == 0).tolist() + [len(steps)]
    before: list[np.ndarray] = []
    for first, end in zip(starts[:-1], starts[1:], strict=True):
        hits = np.flatnonzero(success[first:end] > 0)
        before.append(logits[first : first + (hits[0] if len(hits) else end - first)])
    top = logits[success > 0].mean() if (success > 0).any() else np.nan
    return float((np.concatenate(before).mean() - random_mean) / (top - random_mean))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--episodes", type=int, default=6, help="scripted and random episodes each")
    parser.add_argument("--steps", type=int, nargs="+", default=list(STEPS_PER_EPOCH), help="steps per epoch")
    parser.add_argument("--lr", type=float, nargs="+", default=list(LEARNING_RATES))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--query-every", type=int, default=None, help="default: the run's")
    parser.add_argument("--no-answer-share", type=float, default=None, help="default: the run's")
    parser.add_argument("--landscape", action="store_true", help="door: also f_psi over the hand's (y, z), door shut")
    args = parser.parse_args()
    state, run_config, agent = load_run(args.checkpoint)
    action_dim = int(state["replay"]["actions"].shape[1])
    replay = ReplayBuffer(run_config.replay_capacity, (run_config.image_size, run_config.image_size, 3), action_dim)
    replay.load_state_dict(state["replay"])
    rewards = state["reward_model"]
    positives = np.concatenate([rewards["goals"].numpy(), rewards["answered_positives"].numpy()])
    epochs = len(replay) // run_config.epoch_steps
    env = make_env(run_config.env_id, image_size=run_config.image_size, display_size=64)
    scripted = play(env, "scripted", agent, run_config, args.episodes, seed=10_000)
    random_play = play(env, "random", agent, run_config, args.episodes, seed=20_000)
    landscapes: list[str] = []
    print(
        f"{run_config.env_id}, checkpoint at step {state['step']}: {epochs} epochs of its replay ({len(replay)} "
        f"transitions, {np.nanmean(replay.env_reward[: len(replay)]):.1%} of them successes), {len(positives)} "
        f"positives; the run used {run_config.classifier_steps} steps at lr {run_config.classifier_lr:g}; "
        f"{args.episodes} scripted and random episodes ({scripted['success'].mean():.0%} / "
        f"{random_play['success'].mean():.0%} success states)"
    )  # fmt: skip
    print("steps lr     | f_psi by tenth of the scripted episodes                      | random  goals | rho   credit")
    for steps in args.steps:
        for lr in args.lr:
            setting = {"classifier_steps": steps, "classifier_lr": lr}
            for name in ("query_every", "no_answer_share"):
                if getattr(args, name) is not None:
                    setting[name] = getattr(args, name)
            config = TrainConfig.from_dict({**run_config.to_dict(), **setting})
            started = time.perf_counter()
            model = train(config, replay, positives, agent, epochs, args.seed)
            path = model.logits(scripted["images"])
            random_mean = float(model.logits(random_play["images"]).mean())
            tenth = max(1, run_config.episode_steps // 10)
            by_tenth = " ".join(f"{path[scripted['step'] // tenth == t].mean():+5.1f}" for t in range(10))
            rho = rank_correlation(path, -scripted["distance"])
            share = credit(path, scripted["step"], scripted["success"], random_mean)
            print(
                f"{steps:5d} {lr:.0e} | {by_tenth} | {random_mean:+6.1f} {model.logits(positives).mean():+6.1f} | "
                f"{rho:+.2f} {share:+.2f}   ({len(model.answered_negatives)} no, {len(model.answered_positives)} yes; "
                f"{time.perf_counter() - started:.0f} s)",
                flush=True,
            )  # fmt: skip
            if args.landscape and "door_angle" in env.unwrapped.get_info():
                title, *cells = door_landscape(model, env)
                landscapes += [f"\n{steps} steps at lr {lr:.0e}: {title}", *cells]
    print("\n".join(landscapes))
    env.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
