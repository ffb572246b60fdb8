"""How far random actions get in each simulated task (the exploration table of docs/design.md).

    MUJOCO_GL=egl python bench/exploration.py [--episodes 400] [--tasks door picker pusher]

For each task, 100-step episodes from reset under four random policies: i.i.d. uniform actions; uniform actions
each held for 10 steps (a crude model of temporally correlated exploration); and uniform actions made of pink and
red noise (power spectrum 1/f and 1/f^2 along the episode, learner/exploration.py), what the warm-up acts with
under `exploration_noise_beta` 1 and 2. Each row prints the share of episodes
in which a task-specific milestone was reached at some step, the share that end in success (what evaluation
counts), and the scripted controller's success rate as a yardstick. Milestones:

- pusher: mug touched (moved > 5 mm), moved > 5 cm, brought 5 cm closer to the coaster;
- door: hook's tip in the slot behind the handle bar, door opened > 0.1 rad and > 0.3 rad past its start angle;
- picker: ball touched (moved > 5 mm), ball between the fingers, lifted >= 2 cm, lost (the episode ends with the
  ball's centre more than 2 cm outside its region; the scene keeps it in, so this should read 0).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gymnasium
import numpy as np
import torch

import sim
from learner.exploration import colored_noise, uniform_of
from sim.scripted import success_rate

HOLD_STEPS = 10
# The picker's ball counts as lost when it ends an episode this far (m) from the table's centre along x or y: 2 cm
# outside its region, where a closed gripper no longer reaches it.
LOST_BEYOND = 0.07
Infos = Sequence[dict[str, Any]]


def _moved(key: str, infos: Infos) -> float:
    start = np.asarray(infos[0][key])
    return max(float(np.linalg.norm(np.asarray(info[key])[:2] - start[:2])) for info in infos)


def _between_fingers(info: dict[str, Any]) -> bool:
    offset = np.abs(np.asarray(info["ball_pos"]) - np.asarray(info["hand_pos"]))
    return bool(offset[0] < 0.014 and offset[1] < 0.04 and offset[2] < 0.03)


# Milestones per task: name -> whether an episode (its infos, the reset's first) reached it.
MILESTONES: dict[str, dict[str, Callable[[Infos], bool]]] = {
    "pusher": {
        "mug touched": lambda infos: _moved("mug_pos", infos) > 0.005,
        "mug moved > 5 cm": lambda infos: _moved("mug_pos", infos) > 0.05,
        "mug 5 cm closer": lambda infos: min(i["mug_to_goal"] for i in infos) < infos[0]["mug_to_goal"] - 0.05,
    },
    "door": {
        "hook in the slot": lambda infos: any(info["hooked"] for info in infos),
        "opened > 0.1 rad": lambda infos: max(i["door_angle"] for i in infos) > infos[0]["door_angle"] + 0.1,
        "opened > 0.3 rad": lambda infos: max(i["door_angle"] for i in infos) > infos[0]["door_angle"] + 0.3,
    },
    "picker": {
        "ball touched": lambda infos: _moved("ball_pos", infos) > 0.005,
        "between fingers": lambda infos: any(_between_fingers(info) for info in infos),
        "lifted >= 2 cm": lambda infos: max(i["ball_pos"][2] for i in infos) >= infos[0]["ball_pos"][2] + 0.02,
        "lost": lambda infos: float(np.abs(np.asarray(infos[-1]["ball_pos"][:2])).max()) > LOST_BEYOND,
    },
}


def uniform_actions(env: gymnasium.Env, hold: int, beta: float, generator: torch.Generator) -> np.ndarray:
    """One episode's actions in [-1, 1]: i.i.d. uniform, each held `hold` steps (beta 0), or coloured noise's."""
    steps, dims = sim.MAX_EPISODE_STEPS, int(env.action_space.shape[0])
    if beta > 0:
        return uniform_of(colored_noise(beta, steps, dims, generator)).numpy()
    return np.repeat([env.action_space.sample() for _ in range(0, steps, hold)], hold, axis=0)[:steps]


def random_episodes(task: str, episodes: int, hold: int = 1, beta: float = 0.0, seed: int = 0) -> dict[str, float]:
    """Share of `episodes` random episodes (each action held `hold` steps, or coloured noise of exponent `beta`)
    reaching each milestone of `task`."""
    env = gymnasium.make(sim.TASKS[task])
    env.action_space.seed(seed)
    generator = torch.Generator().manual_seed(seed)
    reached = dict.fromkeys([*MILESTONES[task], "success at some step", "success at the end"], 0)
    try:
        for episode in range(episodes):
            _, info = env.reset(seed=seed + episode)
            infos = [info]
            for action in uniform_actions(env, hold, beta, generator):
                infos.append(env.step(action)[4])
            for name, milestone in MILESTONES[task].items():
                reached[name] += milestone(infos)
            reached["success at some step"] += any(info["success"] for info in infos)
            reached["success at the end"] += infos[-1]["success"]
    finally:
        env.close()
    return {name: count / episodes for name, count in reached.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=400, help="random episodes per task and policy")
    parser.add_argument("--scripted-episodes", type=int, default=100, help="episodes of the scripted controller")
    parser.add_argument("--tasks", nargs="+", choices=sorted(sim.TASKS), default=list(sim.TASKS))
    args = parser.parse_args()
    for task in args.tasks:
        print(f"{task}: scripted controller {success_rate(task, 'scripted', args.scripted_episodes):.0%} success")
        policies = {
            "i.i.d.": random_episodes(task, args.episodes),
            f"held {HOLD_STEPS}": random_episodes(task, args.episodes, hold=HOLD_STEPS),
            "pink": random_episodes(task, args.episodes, beta=1.0),
            "red": random_episodes(task, args.episodes, beta=2.0),
        }
        print(f"  {'milestone':24s} " + " ".join(f"{name:>8s}" for name in policies) + f"   ({args.episodes} each)")
        for milestone in policies["i.i.d."]:
            print(f"  {milestone:24s} " + " ".join(f"{shares[milestone]:8.1%}" for shares in policies.values()))


if __name__ == "__main__":
    main()
