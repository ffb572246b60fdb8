"""Runs end to end through a real temporary SQLite store: answers arriving while training, every algorithm,
a bring-your-own env without success, answers reaching the example sets, SIGTERM re-queueing and SIGKILL resume."""

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

import learner.testing_envs as testing_envs
from app.migrate import upgrade
from app.settings import Settings
from app.store import RunStatus, Store
from learner.checkpoint import checkpoint_path, load_checkpoint
from learner.config import TrainConfig
from learner.envs import encode_png
from learner.train import Trainer
from learner.worker import work

torch.set_num_threads(1)
ROOT = Path(__file__).resolve().parent.parent
ENV = "learner.testing_envs:DotReach-v0"
if "DotReachNoSuccess-v0" not in gym.registry:
    gym.register(
        id="DotReachNoSuccess-v0", entry_point="learner.testing_envs:DotReach", max_episode_steps=50,
        kwargs={"report_success": False, "obs_size": 20},
    )  # fmt: skip


def tiny_config(**overrides: object) -> TrainConfig:
    values: dict[str, object] = dict(
        env_id=ENV, image_size=16, conv_filters=4, hidden_dim=32, batch_size=16, classifier_batch_size=8,
        total_steps=300, episode_steps=25, initial_random_steps=50, epoch_steps=50, classifier_steps=2,
        naive_classifier_steps=20, raq_initial_negatives=40, query_every=50, query_budget=4, eval_every=100,
        eval_episodes=2, checkpoint_every=100, log_every=50, display_size=32, rollout_size=16,
        replay_capacity=1000, heartbeat_seconds=0.2, query_candidates=4,
    )  # fmt: skip
    values.update(overrides)
    return TrainConfig(**values)  # type: ignore[arg-type]


@pytest.fixture
def setup(tmp_path: Path) -> tuple[Settings, Store, int]:
    url = f"sqlite:///{tmp_path / 'raq.sqlite3'}"
    upgrade(url)
    store = Store(url)
    settings = Settings(data_dir=tmp_path, database_url=url, stale_heartbeat_seconds=60.0)
    goal_set = store.create_goal_set(name="dot", image_size=16)
    env = testing_envs.DotReach(obs_size=16, render_size=32)
    for i in range(4):
        env.position = testing_envs.TARGET + np.float32(0.05 * (i - 1.5))
        png = encode_png(env._draw(16))
        store.add_goal_example(
            goal_set_id=goal_set.id, filename=f"goal{i}.png", original=png, original_media_type="image/png",
            width=16, height=16, model_png=png, display_png=encode_png(env._draw(32)),
        )  # fmt: skip
    yield settings, store, goal_set.id
    store.dispose()


def create_run(store: Store, goal_set_id: int | None, config: TrainConfig) -> int:
    run = store.create_run(
        env_id=config.env_id, algorithm=config.algorithm, config=config.to_dict(), seed=config.seed,
        goal_set_id=goal_set_id, total_steps=config.total_steps,
    )  # fmt: skip
    return run.id


def oracle(store: Store, run_id: int, done: threading.Event) -> None:
    """Answers every pending query with its ground truth, from another thread, while the learner trains."""
    while not done.is_set():
        for query in store.pending_queries(run_id=run_id):
            store.answer_query(query_id=query.id, success=bool(query.ground_truth_success), labeler="oracle")
        time.sleep(0.02)


def test_vice_raq_run_end_to_end_with_answers_arriving(setup: tuple[Settings, Store, int]) -> None:
    settings, store, goal_set_id = setup
    config = tiny_config(algorithm="vice_raq")
    run_id = create_run(store, goal_set_id, config)
    done = threading.Event()
    answering = threading.Thread(target=oracle, args=(store, run_id, done), daemon=True)
    answering.start()
    try:
        assert work(settings, worker_name="w1", once=True) == 0
    finally:
        done.set()
        answering.join()
    run = store.get_run(run_id=run_id)
    assert run.status == RunStatus.FINISHED, run.status_reason
    assert run.step == config.total_steps
    names = {metric.name for metric in store.metrics(run_id=run_id)}
    expected = {
        "train/episode_return", "critic/loss", "actor/loss", "alpha/value", "reward/loss", "reward/acc_goal",
        "reward/acc_replay", "reward/mean_logit_goal", "reward/mean_logit_recent", "queries/asked",
        "queries/answered", "queries/yes", "perf/steps_per_second", "perf/updates_per_second", "perf/eta_seconds",
        "eval/success_rate", "eval/return", "reward/agreement_with_answers",
    }  # fmt: skip
    assert expected <= names, expected - names
    agreement = store.metrics(run_id=run_id, names=["reward/agreement_with_answers"])
    assert all(0.0 <= metric.value <= 1.0 for metric in agreement)
    queries = store.list_queries(run_id=run_id)
    assert len(queries) == config.query_budget
    assert all(q.status == "answered" and q.used_at is not None for q in queries[1:])  # all but maybe the last
    assert len({store.query_image(query_id=q.id, resolution="model") for q in queries}) == len(queries)
    for query in queries:  # the label and info describe exactly the state shown
        assert query.ground_truth_success == float(query.info["success"])
        assert query.score is not None and query.strategy == "argmax"
    rollout = store.latest_rollout(run_id=run_id)
    assert rollout is not None and store.rollout_data(rollout_id=rollout.id)[:6] in (b"GIF89a", b"GIF87a")
    messages = [event.message for event in store.events(run_id=run_id, limit=1000)]
    assert any(m.startswith("answers received") for m in messages)
    assert any(m.startswith("warm-up started") for m in messages)
    assert any(m.startswith("checkpoint written") for m in messages)
    assert checkpoint_path(settings.checkpoint_dir, run_id).exists()


@pytest.mark.parametrize(
    ("algorithm", "env_id", "success_metric"),
    [
        ("vice", ENV, True),
        ("raq", ENV, True),
        ("naive_classifier", ENV, True),
        ("sparse", ENV, True),
        ("vice_raq", "DotReachNoSuccess-v0", False),  # bring your own env: 20 px obs, no success flag
    ],
)
def test_every_algorithm_runs(setup: tuple[Settings, Store, int], algorithm: str, env_id: str, success_metric: bool):
    settings, store, goal_set_id = setup
    config = tiny_config(algorithm=algorithm, env_id=env_id, total_steps=150, checkpoint_every=1000)
    run_id = create_run(store, None if algorithm == "sparse" else goal_set_id, config)
    assert work(settings, worker_name="w", once=True) == 0
    run = store.get_run(run_id=run_id)
    assert run.status == RunStatus.FINISHED, run.status_reason
    names = {metric.name for metric in store.metrics(run_id=run_id)}
    assert ("eval/success_rate" in names) == success_metric
    assert "critic/loss" in names and ("reward/loss" in names) == (algorithm != "sparse")
    queries = store.list_queries(run_id=run_id)
    assert (len(queries) > 0) == (algorithm in ("vice_raq", "raq"))
    assert all(q.ground_truth_success is None for q in queries) or success_metric


def test_failed_run_reports_the_reason(setup: tuple[Settings, Store, int]) -> None:
    settings, store, _ = setup
    run_id = create_run(store, None, tiny_config(algorithm="vice"))
    assert work(settings, worker_name="w", once=True) == 1
    run = store.get_run(run_id=run_id)
    assert run.status == RunStatus.FAILED and "needs a goal set" in run.status_reason


@pytest.mark.parametrize("algorithm", ["raq", "vice_raq"])
def test_answers_reach_the_example_sets(setup: tuple[Settings, Store, int], algorithm: str) -> None:
    settings, store, goal_set_id = setup
    config = tiny_config(algorithm=algorithm)
    run_id = create_run(store, goal_set_id, config)
    trainer = Trainer(
        config, store=store, run_id=run_id, worker="w", goal_set_id=goal_set_id,
        checkpoint_file=checkpoint_path(settings.checkpoint_dir, run_id),
    )  # fmt: skip
    trainer._load_goals()
    model = trainer.reward_model
    assert model is not None and len(model.positives) == 4
    yes_image = np.full((16, 16, 3), 200, np.uint8)
    no_image = np.full((16, 16, 3), 10, np.uint8)
    for image, answer in ((yes_image, True), (no_image, False)):
        query = store.post_query(run_id=run_id, env_step=1, model_png=encode_png(image), display_png=b"x", score=1.0)
        store.answer_query(query_id=query.id, success=answer)
    negatives_before = len(model.negatives)
    trainer._read_answers()
    assert len(model.positives) == 5 and np.array_equal(model.positives[-1], yes_image)
    if algorithm == "raq":  # RAQ: a no is a negative
        assert len(model.negatives) == negatives_before + 1 and np.array_equal(model.negatives[-1], no_image)
    else:  # VICE-RAQ: no's are already among the replay negatives
        assert len(model.negatives) == negatives_before
    trainer._read_answers()  # the cursor: nothing is taken twice
    assert len(model.positives) == 5
    trainer.close()


def _spawn_worker(settings: Settings, name: str) -> subprocess.Popen:
    env = dict(os.environ, RAQ_DATA_DIR=str(settings.data_dir), RAQ_DATABASE_URL=settings.resolved_database_url)
    env.update(OMP_NUM_THREADS="1", RAQ_STALE_HEARTBEAT_SECONDS="60")
    command = [sys.executable, "-m", "learner.worker", "--once", "--name", name]
    return subprocess.Popen(command, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def _wait_for(path: Path, process: subprocess.Popen, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert process.poll() is None, process.stdout.read().decode() if process.stdout else ""
        assert time.monotonic() < deadline, "no checkpoint appeared"
        time.sleep(0.02)


def test_sigkilled_learner_is_resumed_from_its_checkpoint(setup: tuple[Settings, Store, int]) -> None:
    settings, store, goal_set_id = setup
    config = tiny_config(algorithm="vice_raq", total_steps=1200, checkpoint_every=100, eval_every=1000)
    run_id = create_run(store, goal_set_id, config)
    path = checkpoint_path(settings.checkpoint_dir, run_id)
    first = _spawn_worker(settings, "first")
    _wait_for(path, first)
    first.send_signal(signal.SIGKILL)
    first.wait(timeout=30)
    state = load_checkpoint(path)
    assert state is not None and 100 <= state["step"] < config.total_steps
    assert store.get_run(run_id=run_id).status in RunStatus.ACTIVE
    time.sleep(0.6)
    resumed = Settings(data_dir=settings.data_dir, database_url=settings.database_url, stale_heartbeat_seconds=0.5)
    assert work(resumed, worker_name="second", once=True) == 0
    run = store.get_run(run_id=run_id)
    assert run.status == RunStatus.FINISHED and run.step == config.total_steps and run.worker == "second"
    messages = [event.message for event in store.events(run_id=run_id, limit=1000)]
    assert f"resumed from checkpoint at step {state['step']}" in messages
    asked = store.list_queries(run_id=run_id)
    assert len(asked) <= config.query_budget  # the budget counts the queries of the killed learner too
    assert len({store.query_image(query_id=q.id, resolution="model") for q in asked}) == len(asked)


def test_sigterm_checkpoints_and_requeues(setup: tuple[Settings, Store, int]) -> None:
    settings, store, goal_set_id = setup
    config = tiny_config(algorithm="vice_raq", total_steps=5000, checkpoint_every=100, eval_every=5000)
    run_id = create_run(store, goal_set_id, config)
    path = checkpoint_path(settings.checkpoint_dir, run_id)
    worker = _spawn_worker(settings, "terminated")
    _wait_for(path, worker)
    worker.send_signal(signal.SIGTERM)
    assert worker.wait(timeout=60) == 0
    run = store.get_run(run_id=run_id)
    assert run.status == RunStatus.QUEUED
    state = load_checkpoint(path)
    assert state is not None and state["step"] == run.step
    messages = [event.message for event in store.events(run_id=run_id, limit=1000)]
    assert any("interrupted" in m and "queued again" in m for m in messages)


def test_visual_pusher_run(setup: tuple[Settings, Store, int]) -> None:
    """The sim's pusher through the same loop: queries carry its display render and ground truth."""
    settings, store, goal_set_id = setup
    config = tiny_config(
        env_id="VisualPusher-v0", algorithm="vice_raq", total_steps=120, eval_episodes=1, display_size=64,
        checkpoint_every=1000,
    )  # fmt: skip
    run_id = create_run(store, goal_set_id, config)
    assert work(settings, worker_name="w", once=True) == 0
    run = store.get_run(run_id=run_id)
    assert run.status == RunStatus.FINISHED, run.status_reason
    queries = store.list_queries(run_id=run_id)
    assert queries and all(q.ground_truth_success in (0.0, 1.0) and "mug_pos" in q.info for q in queries)
    assert "eval/success_rate" in {metric.name for metric in store.metrics(run_id=run_id)}
