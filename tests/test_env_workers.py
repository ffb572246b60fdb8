"""Training envs in worker processes (TrainConfig.env_processes): the same env as in the loop's own process, stepped
at once, with its snapshots, renders and generator state reached through the pipe."""

import os

import numpy as np
import pytest

from contract.envs import display_of_snapshot, make_env, snapshot_of
from contract.settings import Settings
from contract.store import Store
from learner.env_workers import ProcessEnv, WorkerError, process_envs
from learner.train import Outcome, Trainer
from tests.test_learner_run import ENV, _claimed_trainer, create_run, setup, tiny_config

__all__ = ["setup"]  # (the fixture, shared with the loop's tests)


def test_an_env_in_a_worker_process_is_the_env_in_this_one() -> None:
    """Reset, steps, render, snapshots and the generator's state give what the env made here gives, from another
    process; an error in the worker is raised here with its traceback, and a worker that died is reported."""
    here = make_env(ENV, image_size=16, display_size=32)
    [there] = process_envs(1, ENV, image_size=16, display_size=32)
    try:
        assert there.pid is not None and there.pid != os.getpid()
        assert there.action_space == here.action_space
        for env in (here, there):
            env.reset(seed=7)
        actions = np.random.default_rng(0).uniform(-1, 1, (6, 2)).astype(np.float32)
        for action in actions[:3]:
            mine, theirs = here.step(action), there.step(action)
            np.testing.assert_array_equal(mine[0], theirs[0])
            assert mine[1:4] == theirs[1:4] and mine[4]["success"] == theirs[4]["success"]
        snapshot = snapshot_of(there)
        np.testing.assert_array_equal(snapshot, snapshot_of(here))
        state = there.unwrapped.np_random.bit_generator.state
        assert state == here.unwrapped.np_random.bit_generator.state
        for action in actions[3:]:
            here.step(action), there.step(action)
        fallback = np.zeros((16, 16, 3), dtype=np.uint8)
        np.testing.assert_array_equal(  # the render of an earlier state, the env left where it was
            display_of_snapshot(there, snapshot, 32, fallback), display_of_snapshot(here, snapshot, 32, fallback)
        )
        np.testing.assert_array_equal(there.render(), here.render())
        there.unwrapped.np_random.bit_generator.state = state
        here.unwrapped.np_random.bit_generator.state = state
        np.testing.assert_array_equal(there.reset()[0], here.reset()[0])  # (the reset draws from the generator)
        with pytest.raises(WorkerError, match="Traceback"):
            there.unwrapped.restore_snapshot("not a snapshot")
        np.testing.assert_array_equal(there.step(actions[0])[0], here.step(actions[0])[0])  # (still serving)
        there.process.kill()  # a worker that dies says so at the next call, not a hang
        there.process.join()
        with pytest.raises(WorkerError, match="went away"):
            there.step(actions[0])
    finally:
        here.close()
        there.close()
    assert not there.process.is_alive()


def test_a_worker_that_cannot_make_its_env_says_why() -> None:
    with pytest.raises(WorkerError, match="not a registered gymnasium id|NameNotFound|No registered env"):
        process_envs(2, "learner.testing_envs:NoSuchEnv-v0", image_size=16, display_size=32)


def _run(store: Store, settings: Settings, goal_set_id: int, env_processes: bool) -> tuple[Trainer, int, list[str]]:
    config = tiny_config(algorithm="vice_raq", num_envs=2, total_steps=120, env_processes=env_processes)
    run_id = create_run(store, goal_set_id, config)
    trainer = _claimed_trainer(store, settings, run_id, config, goal_set_id)
    calls: list[str] = []
    for index, episode in enumerate(trainer.episodes):
        if env_processes:
            assert isinstance(episode.env, ProcessEnv)
            step_async, step_wait = episode.env.step_async, episode.env.step_wait

            def sent(action, index=index, step_async=step_async):
                calls.append(f"send{index}")
                return step_async(action)

            def received(index=index, step_wait=step_wait):
                calls.append(f"wait{index}")
                return step_wait()

            episode.env.step_async, episode.env.step_wait = sent, received
    try:
        assert trainer.train() == Outcome.FINISHED
    finally:
        trainer.close()
    return trainer, run_id, calls


def test_a_run_with_its_envs_in_processes_is_the_run_with_them_here(setup: tuple[Settings, Store, int]) -> None:
    """num_envs=2, env_processes: both envs are sent their actions before either step is collected (they step at
    once), and the run (replay, evaluations, queries) is the one whose envs step in the loop's own process; the
    workers are gone when the trainer closes."""
    settings, store, goal_set_id = setup
    local, local_id, _ = _run(store, settings, goal_set_id, env_processes=False)
    remote, remote_id, calls = _run(store, settings, goal_set_id, env_processes=True)
    assert calls[:4] == ["send0", "send1", "wait0", "wait1"] and len(calls) == 2 * 120
    assert all(calls[i : i + 4] == calls[:4] for i in range(0, len(calls), 4))
    assert remote.replay.added == local.replay.added == 120
    frames = remote.replay.frames_since(0)
    np.testing.assert_array_equal(frames, local.replay.frames_since(0))

    def evaluations(run_id: int) -> list[tuple[int, float]]:
        return [(m.step, m.value) for m in store.metrics(run_id=run_id, names=["eval/return"])]

    assert evaluations(remote_id) == evaluations(local_id) and len(evaluations(local_id)) == 2

    def queries(run_id: int) -> list[tuple[int, bytes]]:
        return [
            (q.env_step, store.query_image(query_id=q.id, resolution="display"))
            for q in store.list_queries(run_id=run_id, limit=100)
        ]

    assert queries(remote_id) == queries(local_id) and queries(local_id)
    assert all(not episode.env.process.is_alive() for episode in remote.episodes)
