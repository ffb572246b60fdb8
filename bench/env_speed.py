"""Env steps per second for each simulated task, against bare MuJoCo doing the same physics and rendering.

    MUJOCO_GL=egl python bench/env_speed.py [--steps 2000] [--image-size 48]

"bare mujoco" is `mj_step` x frame_skip plus a render of the observation camera on the same model, with no
Python env around it, replaying the env rollout's mocap targets and controls so that the physics does the same
work; the ratio says how much the env wrapper costs. One process, one thread. The two are measured
alternately `--repeats` times and the best of each is kept, so that load from other processes affects both alike.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gymnasium
import mujoco
import numpy as np

import sim

EPISODE_STEPS = sim.MAX_EPISODE_STEPS


def env_steps_per_second(env_id: str, steps: int, image_size: int) -> tuple[float, float]:
    """(wall, CPU) steps/s of `gymnasium.make(env_id)` with random actions, resets included (every 100 steps)."""
    env = gymnasium.make(env_id, image_size=image_size)
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(steps)]
    for action in actions[:50]:  # warm-up: renderer creation, caches
        env.step(action)
    env.reset(seed=0)
    start, cpu_start = time.perf_counter(), time.process_time()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    env.close()
    return steps / elapsed, steps / cpu


def record_rollout(env_id: str, steps: int) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """The same random rollout as `env_steps_per_second`: start states per episode, mocap targets and controls."""
    env = gymnasium.make(env_id, image_size=8)
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(steps)]
    data = env.unwrapped.data
    starts, mocaps, controls = [data.qpos.copy()], [], []
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        mocaps.append(data.mocap_pos.copy())
        controls.append(data.ctrl.copy())
        if terminated or truncated:
            env.reset()
            starts.append(data.qpos.copy())
    env.close()
    return starts, mocaps, controls


def bare_mujoco_steps_per_second(env_id: str, steps: int, image_size: int) -> tuple[float, float]:
    """(wall, CPU) steps/s of mj_step x frame_skip + one render of the observation camera, on the env's model.

    The mocap targets and controls of the env's rollout are replayed, so the physics does the same work.
    """
    starts, mocaps, controls = record_rollout(env_id, steps)
    env = gymnasium.make(env_id, image_size=image_size)
    task_env = env.unwrapped
    model, data = task_env.model, mujoco.MjData(task_env.model)
    frame_skip, camera = task_env.frame_skip, task_env.camera_name
    renderer = mujoco.Renderer(model, image_size, image_size)
    for _ in range(50):
        mujoco.mj_step(model, data, nstep=frame_skip)
        renderer.update_scene(data, camera=camera)
        renderer.render()
    start, cpu_start = time.perf_counter(), time.process_time()
    for step in range(steps):
        if step % EPISODE_STEPS == 0:
            mujoco.mj_resetData(model, data)
            data.qpos[:] = starts[step // EPISODE_STEPS]
            mujoco.mj_forward(model, data)
        data.mocap_pos[:] = mocaps[step]
        data.ctrl[:] = controls[step]
        mujoco.mj_step(model, data, nstep=frame_skip)
        renderer.update_scene(data, camera=camera)
        image = renderer.render()
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    assert image.shape == (image_size, image_size, 3) and image.dtype == np.uint8
    renderer.close()
    env.close()
    return steps / elapsed, steps / cpu


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=2000, help="timed steps per measurement")
    parser.add_argument("--image-size", type=int, default=48, help="observation side in pixels")
    parser.add_argument("--repeats", type=int, default=5, help="alternate measurements; the best of each is kept")
    args = parser.parse_args(argv)
    print(f"MUJOCO_GL={os.environ.get('MUJOCO_GL')}  image {args.image_size}px  steps {args.steps} x {args.repeats}")
    print("best of the repeats; 'cpu' counts the CPU seconds of this process (all its threads), wall the elapsed time")
    header = ("env/s wall", 11), ("bare/s wall", 12), ("ratio", 7), ("env/s cpu", 11), ("bare/s cpu", 12), ("ratio", 7)
    print(f"{'task':<18}" + "".join(f"{title:>{width}}" for title, width in header))
    for env_id in sim.TASKS.values():
        env_rate, bare_rate = np.zeros(2), np.zeros(2)
        for _ in range(args.repeats):
            env_rate = np.maximum(env_rate, env_steps_per_second(env_id, args.steps, args.image_size))
            bare_rate = np.maximum(bare_rate, bare_mujoco_steps_per_second(env_id, args.steps, args.image_size))
        ratio = env_rate / bare_rate
        print(
            f"{env_id:<18}{env_rate[0]:>11.0f}{bare_rate[0]:>12.0f}{ratio[0]:>7.0%}"
            f"{env_rate[1]:>11.0f}{bare_rate[1]:>12.0f}{ratio[1]:>7.0%}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
