"""Env steps per second for each simulated task, against bare MuJoCo doing the same physics and rendering.

    MUJOCO_GL=egl python bench/env_speed.py [--steps 2000] [--image-size 48]

"bare mujoco" is `mj_step` x frame_skip plus a render of the observation camera on the same model, with no
Python env around it; the ratio says how much the env wrapper costs. One process, one thread.
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


def env_steps_per_second(env_id: str, steps: int, image_size: int) -> float:
    """Steps/s of `gymnasium.make(env_id)` with random actions, resets included (every 100 steps)."""
    env = gymnasium.make(env_id, image_size=image_size)
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(steps)]
    for action in actions[:50]:  # warm-up: renderer creation, caches
        env.step(action)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    elapsed = time.perf_counter() - start
    env.close()
    return steps / elapsed


def bare_mujoco_steps_per_second(env_id: str, steps: int, image_size: int) -> float:
    """Steps/s of mj_step x frame_skip + one render of the observation camera, on the env's own model."""
    env = gymnasium.make(env_id, image_size=image_size)
    env.reset(seed=0)
    task_env = env.unwrapped
    model, data = task_env.model, mujoco.MjData(task_env.model)
    data.qpos[:] = task_env.data.qpos
    data.mocap_pos[:] = task_env.data.mocap_pos
    frame_skip, camera = task_env.frame_skip, task_env.camera_name
    renderer = mujoco.Renderer(model, image_size, image_size)
    for _ in range(50):
        mujoco.mj_step(model, data, nstep=frame_skip)
        renderer.update_scene(data, camera=camera)
        renderer.render()
    start = time.perf_counter()
    for _ in range(steps):
        mujoco.mj_step(model, data, nstep=frame_skip)
        renderer.update_scene(data, camera=camera)
        image = renderer.render()
    elapsed = time.perf_counter() - start
    assert image.shape == (image_size, image_size, 3) and image.dtype == np.uint8
    renderer.close()
    env.close()
    return steps / elapsed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=2000, help="timed steps per measurement")
    parser.add_argument("--image-size", type=int, default=48, help="observation side in pixels")
    args = parser.parse_args(argv)
    print(f"MUJOCO_GL={os.environ.get('MUJOCO_GL')}  image {args.image_size}x{args.image_size}  steps {args.steps}")
    print(f"{'task':<18}{'env steps/s':>12}{'bare mujoco/s':>15}{'ratio':>8}")
    for env_id in sim.TASKS.values():
        env_rate = env_steps_per_second(env_id, args.steps, args.image_size)
        bare_rate = bare_mujoco_steps_per_second(env_id, args.steps, args.image_size)
        print(f"{env_id:<18}{env_rate:>12.0f}{bare_rate:>15.0f}{env_rate / bare_rate:>8.0%}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
