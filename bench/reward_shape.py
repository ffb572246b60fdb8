"""Does a run's learned reward f_psi lead toward success? f_psi against the distance to the goal, from a checkpoint.

    MUJOCO_GL=egl python bench/reward_shape.py bench/out/door-vice_raq-seed0/data/checkpoints/run-1/checkpoint.pt

Plays `--episodes` episodes each of the scripted controller (which succeeds), the run's own policy (deterministic)
and uniformly random actions on the run's task, scores every observation with the checkpoint's f_psi, and prints
per policy: mean f_psi by distance-to-goal bin (the env's own measure: door angle error, ball or mug to goal) and
by tenth of the episode (along the scripted path: approach, grasp or hook, then the motion that succeeds), the
rank correlation of f_psi with closeness, and where the policy ends. A reward that SAC can climb rises as the
distance falls along the scripted path; one that is flat until the goal gives SAC nothing to follow. Before that
it prints what the run has collected (its replay's successes and f_psi's top, per 5,000 transitions) and, on the
door, f_psi with the door shut over the hand's (y, z): where the reward draws the hand before anything opens.
"""

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from contract.config import TrainConfig  # noqa: E402
from contract.envs import make_env, model_image, scale_action  # noqa: E402
from learner.checkpoint import load_checkpoint  # noqa: E402
from learner.reward import RewardModel  # noqa: E402
from learner.sac import SACAgent  # noqa: E402
from sim.scripted import scripted_action  # noqa: E402

DISTANCE_KEYS = ("door_angle_error", "ball_to_goal", "mug_to_goal")
"""The info entry each simulated task reports as its distance to success (door, picker, pusher)."""


def rank_correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's rho (ranks, ties broken by order: fine for continuous values)."""
    ranks_a, ranks_b = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ranks_a, ranks_b)[0, 1])


def play(env, policy: str, agent: SACAgent, config: TrainConfig, episodes: int, seed: int) -> dict[str, np.ndarray]:
    """Observations, distances, successes of every step of `episodes` episodes, and each episode's last distance
    and success."""
    images, distances, successes, final, final_success, steps = [], [], [], [], [], []
    rng = np.random.default_rng(seed)
    space = env.action_space
    for episode in range(episodes):
        raw, info = env.reset(seed=seed + episode)
        obs = model_image(raw, config.image_size)
        key = next(k for k in DISTANCE_KEYS if k in info)
        for step in range(config.episode_steps):
            if policy == "scripted":
                action = scripted_action(env)
            elif policy == "learned":
                action = scale_action(agent.act(obs, deterministic=True), space)
            else:
                action = rng.uniform(space.low, space.high).astype(np.float32)
            raw, _, terminated, truncated, info = env.step(action)
            obs = model_image(raw, config.image_size)
            images.append(obs)
            distances.append(float(info[key]))
            successes.append(float(info["success"]))
            steps.append(step)
            if terminated or truncated:
                break
        final.append(distances[-1])
        final_success.append(successes[-1])
    return {
        "images": np.stack(images), "distance": np.array(distances), "success": np.array(successes),
        "final": np.array(final), "final_success": np.array(final_success), "step": np.array(steps),
    }  # fmt: skip


def load_run(checkpoint: Path) -> tuple[dict[str, Any], TrainConfig, SACAgent]:
    """A run's checkpoint with a reward classifier, its config (on the CPU) and its SAC agent."""
    state = load_checkpoint(checkpoint)
    if state is None or state.get("reward_model") is None:
        raise SystemExit(f"{checkpoint}: no checkpoint with a reward classifier")
    config = TrainConfig.from_dict({**json.loads(state["config"]), "device": "cpu"})
    agent = SACAgent.for_run(config, action_dim=int(state["agent"]["actor"]["trunk.4.bias"].shape[0]) // 2)
    agent.load_state_dict(state["agent"])
    return state, config, agent


def replay_summary(model: RewardModel, replay: dict[str, Any], block: int = 5000) -> list[str]:
    """What the run has seen, as lines to print: per `block` transitions of its replay (in the order collected),
    the share that are successes and f_psi's maximum and 99th percentile on their observations s'."""
    frames, next_slot = replay["frames"].numpy(), replay["next_slot"].numpy()
    success = replay.get("env_reward", replay.get("success")).numpy()  # (a classifier run's: success(s'))
    logits = model.logits(frames[next_slot])
    lines = [f"replay: {len(next_slot)} transitions; per {block:,}: successes, f_psi max and 99th percentile"]
    for first in range(0, len(next_slot), block):
        part = slice(first, first + block)
        lines.append(
            f"  {first:>7,}+  {np.nanmean(success[part]):6.1%}  max {logits[part].max():+5.1f}  "
            f"p99 {np.quantile(logits[part], 0.99):+5.1f}"
        )
    return lines


def door_landscape(model: RewardModel, env: gym.Env, columns: int = 8, rows: int = 7) -> list[str]:
    """f_psi with the door shut over the hook's (y, z) at the handle's x, as lines to print (highest z first): where
    the learned reward draws the hand before the door moves. Marks the cell nearest the slot behind the bar (S),
    where hooking starts, and the one nearest the hand in a success state (G: the scripted pull's end, as in the
    goal images)."""
    door = env.unwrapped
    snapshot = door.state_snapshot()
    door.set_door_angle(0.0)
    slot = door.handle_pos
    for _ in range(200):  # the scripted controller from this state, to where the goal images are (14-32 steps)
        if door.get_info()["success"]:
            break
        door.step(scripted_action(door))
    else:
        raise RuntimeError("the scripted controller did not open the door in 200 steps")
    goal_hand = door.hand_pos
    low, high = np.asarray(door.hand_low), np.asarray(door.hand_high)
    ys, zs = np.linspace(low[1], high[1], columns), np.linspace(low[2], high[2], rows)[::-1]
    marks = {
        (int(np.abs(zs - p[2]).argmin()), int(np.abs(ys - p[1]).argmin())): m
        for p, m in ((slot, "S"), (goal_hand, "G"))
    }
    lines = [f"f_psi with the door shut, hand x {slot[0]:+.2f}; columns y {ys[0]:+.2f} (nearest the robot) to "
             f"{ys[-1]:+.2f} (the door), rows z from {zs[0]:.2f} down:"]  # fmt: skip
    images = []
    for z in zs:
        for y in ys:
            door.set_door_angle(0.0)
            door.set_hand_pos(np.array([slot[0], y, z]))
            images.append(model_image(door.render_image(door.image_size), model.config.image_size))
    logits = model.logits(np.stack(images)).reshape(rows, columns)
    for i, z in enumerate(zs):
        cells = " ".join(f"{logits[i, j]:+5.1f}{marks.get((i, j), ' ')}" for j in range(columns))
        lines.append(f"  z {z:.2f} {cells}")
    door.restore_snapshot(snapshot)
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--bins", type=int, default=6)
    args = parser.parse_args()
    state, config, agent = load_run(args.checkpoint)
    model = RewardModel.for_run(config, np.random.default_rng(0))
    model.load_state_dict(state["reward_model"])
    env = make_env(config.env_id, image_size=config.image_size, display_size=64)
    print(f"{config.env_id} at step {state['step']}: f_psi of {model.net.__class__.__name__}, {args.episodes} "
          f"episodes per policy; {len(model.answered_positives)} answered yes, {len(model.goals)} goals")  # fmt: skip
    played = {policy: play(env, policy, agent, config, args.episodes, seed=10_000) for policy in
              ("scripted", "learned", "random")}  # fmt: skip
    everything = np.concatenate([p["distance"] for p in played.values()])
    edges = np.quantile(everything, np.linspace(0, 1, args.bins + 1))
    print(f"goal images: f_psi mean {model.logits(model.goals).mean():+.2f}")
    print("\n" + "\n".join(replay_summary(model, state["replay"])))
    for policy, data in played.items():
        logits = model.logits(data["images"])
        bins = np.clip(np.searchsorted(edges, data["distance"], side="right") - 1, 0, args.bins - 1)
        by_bin = "  ".join(
            f"[{edges[b]:.3f},{edges[b + 1]:.3f}) {logits[bins == b].mean():+6.2f} (n={np.sum(bins == b)})"
            for b in range(args.bins) if np.any(bins == b)
        )  # fmt: skip
        success = data["success"] > 0
        print(f"\n{policy}: final distance mean {data['final'].mean():.3f}, success states {success.mean():.1%}")
        print(f"  rank correlation of f_psi with closeness: {rank_correlation(logits, -data['distance']):+.2f}")
        print(f"  f_psi on success states {logits[success].mean() if success.any() else float('nan'):+.2f}, "
              f"others {logits[~success].mean():+.2f}")  # fmt: skip
        print(f"  f_psi by distance bin: {by_bin}")
        ended = data["final_success"] > 0
        missed = " ".join(f"{d:.3f}" for d in np.sort(data["final"][~ended]))
        print(f"  episodes ending in success {ended.sum()} of {len(ended)}; the others end at {missed or '-'}")
        tenth = max(1, config.episode_steps // 10)
        by_time = " ".join(f"{logits[data['step'] // tenth == t].mean():+.1f}" for t in range(10))
        print(f"  f_psi by tenth of the episode: {by_time}")
    if "door_angle" in env.unwrapped.get_info():
        print("\n" + "\n".join(door_landscape(model, env)))
    env.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
