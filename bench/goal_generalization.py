"""Before any "yes": does f_psi, trained on a task's few goal photos against exploration frames, rate frames nearer
success higher? As a run trains it, on randomly shifted images, and with "no" answers on near misses, in one run.

    MUJOCO_GL=egl python bench/goal_generalization.py --task picker [--steps 1000] [--pad 8] [--no-share 0.05]

This is the classifier of a VICE-RAQ run before the person's first "yes": positives are the goal photos alone,
negatives the policy's replay, which early on is exploration. The frames come from `--episodes` episodes of the
warm-up's pink-noise actions (the replay) and `--scripted` episodes of the scripted controller (a path that
succeeds). Three f_psi (the run's network, mixup, lr and batch; the sigmoid form, since a near-uniform policy's
log pi is a constant) train side by side on the same batches: as a run's, on images moved by DrQ's random shift,
and with `--no-answers` frames of other scripted episodes 3-12 cm from the goal (the near misses a question asks
about before any success) as `--no-share` of its negatives, as VICE-RAQ's "no" answers are. Every
`--every` steps it prints, for each: the held-out replay accuracy and mean f_psi on the replay, f_psi's rank
correlation with closeness along the scripted path and along the replay, f_psi on the path by distance to the goal,
and the distance of the replay frame f_psi rates highest and of its top 1% (the frames a query asks about). A
reward SAC can climb correlates with closeness; a classifier that only knows the goal photos' pixels rates everything
else alike.
"""

import argparse
import os
import sys
from pathlib import Path

import numpy as np
import torch

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.reward_shape import DISTANCE_KEYS, rank_correlation  # noqa: E402
from contract.config import TrainConfig  # noqa: E402
from contract.envs import make_env, model_image, scale_action  # noqa: E402
from learner.exploration import colored_noise, uniform_of  # noqa: E402
from learner.replay import random_shift, shift_pad  # noqa: E402
from learner.reward import RewardModel  # noqa: E402
from sim import PRESETS, TASKS  # noqa: E402
from sim.goals import make_goal_examples  # noqa: E402
from sim.scripted import scripted_action  # noqa: E402

VARIANTS = ("plain", "shifted", "no answers")
"""The f_psi trained side by side: as a run's, on randomly shifted images, and with "no" answers on near misses as
`--no-share` of its negatives (VICE-RAQ's `no_answer_share`)."""
PATH_BINS = (0.03, 0.05, 0.08, 0.12, 0.16)
"""Distance-to-goal bin edges (m) for f_psi's mean along the scripted path: success, then ever farther."""


def frames(env, episodes: int, steps: int, scripted: bool, seed: int, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Every observation of `episodes` episodes (pink-noise actions, or the scripted controller's) and its distance
    to success."""
    images, distances = [], []
    generator = torch.Generator().manual_seed(seed)
    space = env.action_space
    for episode in range(episodes):
        _, info = env.reset(seed=seed + episode)
        key = next(k for k in DISTANCE_KEYS if k in info)
        noise = uniform_of(colored_noise(1.0, steps, space.shape[0], generator)).numpy()
        for step in range(steps):
            action = scripted_action(env) if scripted else scale_action(noise[step], space)
            raw, _, terminated, truncated, info = env.step(action)
            images.append(model_image(raw, size))
            distances.append(float(info[key]))
            if terminated or truncated:
                break
    return np.stack(images), np.array(distances)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="picker", choices=sorted(TASKS))
    parser.add_argument("--goals", type=int, default=10, help="goal photos (the benches' count)")
    parser.add_argument("--episodes", type=int, default=40, help="pink-noise episodes: the replay")
    parser.add_argument("--scripted", type=int, default=10, help="scripted episodes: the path to success")
    parser.add_argument("--steps", type=int, default=1000, help="classifier steps")
    parser.add_argument("--every", type=int, default=250, help="print every this many steps")
    parser.add_argument("--no-answers", type=int, default=20, help='near misses answered "no" (the third f_psi)')
    parser.add_argument("--no-share", type=float, default=0.25, help='share of the third\'s negatives answered "no"')
    parser.add_argument("--pad", type=int, default=None, help="the second's shift in pixels (default: the run's)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    config = TrainConfig(algorithm="raq", precision="fp32")
    size = config.image_size
    pad = shift_pad(size) if args.pad is None else args.pad
    episode_steps = PRESETS[TASKS[args.task]].get("episode_steps", config.episode_steps)
    goals = np.stack([g.image for g in make_goal_examples(args.task, args.goals, seed=0, image_size=size)])
    env = make_env(TASKS[args.task], image_size=size, display_size=64)
    replay, replay_distance = frames(env, args.episodes, episode_steps, False, 10_000 + args.seed, size)
    path, path_distance = frames(env, args.scripted, episode_steps, True, 20_000 + args.seed, size)
    other_path, other_distance = frames(env, args.scripted, episode_steps, True, 30_000 + args.seed, size)
    env.close()
    near = np.flatnonzero((other_distance >= PATH_BINS[0]) & (other_distance < PATH_BINS[3]))
    no_answers = other_path[rng.choice(near, size=min(args.no_answers, len(near)), replace=False)]
    no_count = round(args.no_share * config.classifier_batch_size)
    held = rng.random(len(replay)) < 0.2
    train = np.flatnonzero(~held)
    path_bin = np.digitize(path_distance, PATH_BINS)
    print(f"{args.task}: {len(goals)} goal photos, replay {len(replay)} frames (distance median "
          f"{np.median(replay_distance):.3f}, min {replay_distance.min():.3f}), scripted path {len(path)} frames, "
          f"per distance bin (edges {PATH_BINS} m) {' '.join(map(str, np.bincount(path_bin, minlength=6)))}; "
          f"shift pad {pad} px",
          flush=True)  # fmt: skip
    models = {name: RewardModel.for_run(config, np.random.default_rng(args.seed)) for name in VARIANTS}
    for name in VARIANTS[1:]:
        models[name].load_state_dict(models["plain"].state_dict())  # the same start
    batch = config.classifier_batch_size
    for step in range(1, args.steps + 1):
        positives = goals[rng.integers(0, len(goals), batch)]
        negatives = replay[train[rng.integers(0, len(train), batch)]]
        answered = np.concatenate([no_answers[rng.integers(0, len(no_answers), no_count)], negatives[no_count:]])
        shifted = random_shift(positives, pad, rng), random_shift(negatives, pad, rng)
        models["plain"].update_classifier(positives, negatives, accuracy=False)
        models["shifted"].update_classifier(*shifted, accuracy=False)
        models["no answers"].update_classifier(positives, answered, accuracy=False)
        if step % args.every and step != args.steps:
            continue
        for name, model in models.items():
            on_replay, on_path = model.logits(replay), model.logits(path)
            top = np.argsort(on_replay)[::-1]
            top_share_distance = np.median(replay_distance[top[: max(1, len(top) // 100)]])
            by_distance = " ".join(
                f"{on_path[path_bin == b].mean():+.1f}" if np.any(path_bin == b) else "-" for b in range(6)
            )
            print(
                f"step {step:>5} {name:>10}: acc goals {np.mean(model.logits(goals) > 0):.2f}, held-out replay "
                f"{np.mean(on_replay[held] < 0):.2f} (mean f {on_replay.mean():+.1f}); rho(f, closeness) path "
                f"{rank_correlation(on_path, -path_distance):+.2f}, replay "
                f"{rank_correlation(on_replay, -replay_distance):+.2f}; f on the path by distance {by_distance}; "
                f"replay's top frame at {replay_distance[top[0]]:.3f}, top 1% {top_share_distance:.3f}",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
