"""Runs end to end through a real temporary SQLite store: answers arriving while training, every algorithm,
a bring-your-own env without success, answers reaching the example sets, SIGTERM re-queueing and SIGKILL resume."""

import functools
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import create_run, learn_once_beside
from PIL import Image

from contract.algorithms import ALGORITHM_SPECS
from contract.config import TrainConfig
from contract.envs import decode_image, encode_png, model_image, scale_action
from contract.settings import Settings
from contract.store import RunStatus, Store
from learner.checkpoint import checkpoint_path, load_checkpoint
from learner.reward import RewardModel
from learner.train import Outcome, Runner, open_runner, train
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
def setup(dot_reach: tuple[Settings, Store, int]) -> tuple[Settings, Store, int]:
    return dot_reach


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
    assert learn_once_beside(settings, functools.partial(oracle, store, run_id)) == 0
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
    ("algorithm", "env_id", "success_metric", "pipeline"),
    [
        ("vice", ENV, True, "host"),
        ("raq", ENV, True, "host"),
        ("naive_classifier", ENV, True, "host"),
        ("sparse", ENV, True, "host"),
        ("hand_distance", ENV, True, "host"),
        ("vice_raq", "DotReachNoSuccess-v0", False, "host"),  # bring your own env: 20 px obs, no success flag
        # the GPU path's code (replay, sampling, rewards and classifier steps on the device), eagerly on the CPU
        ("vice_raq", ENV, True, "device"),
        ("raq", ENV, True, "device"),
        ("sparse", ENV, True, "device"),
        ("hand_distance", ENV, True, "device"),
    ],
)
def test_every_algorithm_runs(
    setup: tuple[Settings, Store, int], algorithm: str, env_id: str, success_metric: bool, pipeline: str
) -> None:
    settings, store, goal_set_id = setup
    config = tiny_config(
        algorithm=algorithm, env_id=env_id, total_steps=150, checkpoint_every=1000, replay_pipeline=pipeline
    )
    spec = ALGORITHM_SPECS[algorithm]
    run_id = create_run(store, goal_set_id if spec.needs_goals else None, config)
    assert work(settings, worker_name="w", once=True) == 0
    run = store.get_run(run_id=run_id)
    assert run.status == RunStatus.FINISHED, run.status_reason
    names = {metric.name for metric in store.metrics(run_id=run_id)}
    assert ("eval/success_rate" in names) == success_metric
    assert "critic/loss" in names and ("reward/loss" in names) == spec.classifier
    if spec.env_reward == "hand_distance":  # minus the dot's distance to the target: below 0 until it is on it
        batch_rewards = [m.value for m in store.metrics(run_id=run_id, names=["reward/batch_mean"])]
        assert batch_rewards and all(-2.9 < reward < 0 for reward in batch_rewards), batch_rewards
    queries = store.list_queries(run_id=run_id)
    assert (len(queries) > 0) == (algorithm in ("vice_raq", "raq"))
    assert all(q.ground_truth_success is None for q in queries) or success_metric
    setup_event = next(e.message for e in store.events(run_id=run_id, limit=1000) if "setting up" in e.message)
    assert ("replay sampled on cpu" in setup_event) == (pipeline == "device"), setup_event


@pytest.mark.parametrize("pipeline", ["host", "device"])
def test_a_run_stored_with_retired_options_loads_and_trains(setup: tuple[Settings, Store, int], pipeline: str) -> None:
    """A run stored by an earlier version with options since removed (n-step returns, f_psi's label smoothing and
    gradient penalty, reward centering, envs in worker processes) trains to its end without them."""
    settings, store, goal_set_id = setup
    config = tiny_config(total_steps=150, checkpoint_every=1000, replay_pipeline=pipeline)
    retired = {"n_step": 3, "classifier_label_smoothing": 0.2, "classifier_gradient_penalty": 10.0,
               "reward_centering": True, "env_processes": True}  # fmt: skip
    run = store.create_run(
        env_id=config.env_id, algorithm=config.algorithm, config={**config.to_dict(), **retired}, seed=config.seed,
        goal_set_id=goal_set_id, total_steps=config.total_steps,
    )  # fmt: skip
    assert work(settings, worker_name="w", once=True) == 0
    stored = store.get_run(run_id=run.id)
    assert stored.status == RunStatus.FINISHED, stored.status_reason
    assert {name: stored.config[name] for name in retired} == retired  # (what the run was stored with stays)
    assert "reward/offset" not in {metric.name for metric in store.metrics(run_id=run.id)}


def test_failed_run_reports_the_reason(setup: tuple[Settings, Store, int]) -> None:
    settings, store, _ = setup
    run_id = create_run(store, None, tiny_config(algorithm="vice"))
    assert work(settings, worker_name="w", once=True) == 1
    run = store.get_run(run_id=run_id)
    assert run.status == RunStatus.FAILED and "needs a goal set" in run.status_reason
    no_hand = create_run(store, None, tiny_config(algorithm="hand_distance", env_id="VisualPusher-v0"))
    assert work(settings, worker_name="w", once=True) == 1
    run = store.get_run(run_id=no_hand)
    assert run.status == RunStatus.FAILED and "info['hand_distance']" in run.status_reason, run.status_reason


@pytest.mark.parametrize(("algorithm", "no_answer_share"), [("raq", 0.0), ("vice_raq", 0.25), ("vice_raq", 0.0)])
def test_answers_reach_the_example_sets(
    setup: tuple[Settings, Store, int], algorithm: str, no_answer_share: float
) -> None:
    settings, store, goal_set_id = setup
    config = tiny_config(algorithm=algorithm, no_answer_share=no_answer_share)
    run_id = create_run(store, goal_set_id, config)
    runner = open_runner(
        config, store=store, run_id=run_id, worker="w", goal_set_id=goal_set_id,
        checkpoint_file=checkpoint_path(settings.checkpoint_dir, run_id),
    )  # fmt: skip
    trainer = runner.trainer
    trainer.load_goals()
    model = trainer.reward_model
    assert model is not None and len(model.positives) == 4
    yes_image = np.full((16, 16, 3), 200, np.uint8)
    no_image = np.full((16, 16, 3), 10, np.uint8)
    for image, answer in ((yes_image, True), (no_image, False)):
        query = store.post_query(run_id=run_id, env_step=1, model_png=encode_png(image), display_png=b"x", score=1.0)
        store.answer_query(query_id=query.id, success=answer)
    negatives_before = len(model.negatives)
    assert trainer.queries is not None
    trainer.queries.read_answers()
    assert len(model.positives) == 5 and np.array_equal(model.positives[-1], yes_image)
    if algorithm == "raq" or no_answer_share > 0:  # RAQ: a no is a negative; VICE-RAQ: kept for its share
        assert len(model.negatives) == negatives_before + 1 and np.array_equal(model.negatives[-1], no_image)
    else:  # the paper's VICE-RAQ: no's are already among the replay negatives
        assert len(model.negatives) == negatives_before
    trainer.queries.read_answers()  # the cursor: nothing is taken twice
    assert len(model.positives) == 5
    runner.close()


def _spawn_worker(settings: Settings, name: str) -> subprocess.Popen:
    env = dict(os.environ, RAQ_DATA_DIR=str(settings.data_dir), RAQ_DATABASE_URL=settings.resolved_database_url)
    env.update(OMP_NUM_THREADS="1", RAQ_STALE_HEARTBEAT_SECONDS="60")
    command = [sys.executable, "-m", "learner.worker", "--once", "--name", name]
    return subprocess.Popen(command, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def _wait_for(path: Path, process: subprocess.Popen, timeout: float = 240.0) -> None:
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert process.poll() is None, process.stdout.read().decode() if process.stdout else ""
        assert time.monotonic() < deadline, "no checkpoint appeared"
        time.sleep(0.02)


def test_sigkilled_learner_is_resumed_from_its_checkpoint(setup: tuple[Settings, Store, int]) -> None:
    """Answers the killed learner read after its checkpoint are read again by the resumed one (none lost, none
    counted twice), and the metrics it recorded after the checkpoint are replaced, not duplicated."""
    settings, store, goal_set_id = setup
    config = tiny_config(algorithm="vice_raq", total_steps=1200, checkpoint_every=300, eval_every=1000)
    run_id = create_run(store, goal_set_id, config)
    path = checkpoint_path(settings.checkpoint_dir, run_id)
    first = _spawn_worker(settings, "first")
    _wait_for(path, first)  # step 300: the 4 queries (steps 50 to 200) are posted
    pending = store.pending_queries(run_id=run_id)
    assert pending
    yes = 0
    for i, query in enumerate(pending):
        store.answer_query(query_id=query.id, success=i % 2 == 0, labeler="test")
        yes += i % 2 == 0
    deadline = time.monotonic() + 240  # generous: a shared 2-core machine can be slow
    while any(store.get_query(query_id=q.id).used_at is None for q in pending):  # read at step 350
        assert first.poll() is None and time.monotonic() < deadline, "the learner did not read the answers"
        time.sleep(0.01)
    first.send_signal(signal.SIGKILL)
    first.wait(timeout=30)
    state = load_checkpoint(path)
    assert state is not None and state["step"] == 300  # killed after reading the answers, before checkpointing
    assert len(state["reward_model"]["answered_positives"]) == 0
    assert store.get_run(run_id=run_id).status in RunStatus.ACTIVE
    time.sleep(0.6)
    resumed = Settings(data_dir=settings.data_dir, database_url=settings.database_url, stale_heartbeat_seconds=0.5)
    assert work(resumed, worker_name="second", once=True) == 0
    run = store.get_run(run_id=run_id)
    assert run.status == RunStatus.FINISHED and run.step == config.total_steps and run.worker == "second"
    messages = [event.message for event in store.events(run_id=run_id, limit=1000)]
    assert any(m.startswith(f"resumed from checkpoint at step {state['step']}; ") for m in messages), messages
    final = load_checkpoint(path)
    assert final is not None and final["step"] == config.total_steps
    assert len(final["reward_model"]["answered_positives"]) == yes
    assert len(final["reward_model"]["answered_negatives"]) == len(pending) - yes  # each no once, for its share
    seen: set[tuple[str, int]] = set()
    for metric in store.metrics(run_id=run_id):
        assert (metric.name, metric.step) not in seen, f"{metric.name} recorded twice at step {metric.step}"
        seen.add((metric.name, metric.step))
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


def _lag_one_correlation(actions: np.ndarray, episode_steps: int) -> float:
    """Mean product of neighbouring actions within episodes, over their variance."""
    episodes = actions.reshape(-1, episode_steps, actions.shape[-1])
    return float((episodes[:, 1:] * episodes[:, :-1]).mean() / actions.var())


def test_coloured_exploration_noise_makes_an_episodes_actions_agree_and_the_run_learns_on(
    setup: tuple[Settings, Store, int],
) -> None:
    """exploration_noise_beta=1 (pink): the warm-up's uniform actions and the policy's samples follow each env's
    sequence, so neighbouring actions of an episode correlate (i.i.d. ones do not), each env has its own, and the
    run finishes."""
    settings, store, goal_set_id = setup
    correlations = {}
    for beta in (0.0, 1.0):
        config = tiny_config(
            total_steps=300, initial_random_steps=200, num_envs=2, exploration_noise_beta=beta, checkpoint_every=1000
        )
        run_id = create_run(store, goal_set_id, config)
        runner = _claimed_runner(store, settings, run_id, config, goal_set_id)
        trainer = runner.trainer
        try:
            assert train(runner) == Outcome.FINISHED
        finally:
            runner.close()
        actions = trainer.replay.actions[: trainer.replay.added]
        assert np.abs(actions).max() <= 1.0
        by_env = [actions[index::2] for index in range(2)]  # (the two envs' steps alternate)
        warm_up = [env[: config.initial_random_steps // 2] for env in by_env]
        policy = [env[config.initial_random_steps // 2 :] for env in by_env]
        correlations[beta] = [_lag_one_correlation(a, config.episode_steps) for a in (*warm_up, *policy)]
        if beta > 0:
            assert not np.allclose(by_env[0], by_env[1])
    assert all(abs(value) < 0.2 for value in correlations[0.0][:2]), correlations
    assert all(value > 0.3 for value in correlations[1.0]), correlations


def _claimed_runner(store: Store, settings: Settings, run_id: int, config: TrainConfig, goal_set_id: int | None,
                    interrupt: threading.Event | None = None) -> Runner:  # fmt: skip
    run = store.claim_next_run(worker="w")
    assert run is not None and run.id == run_id
    return open_runner(
        config, store=store, run_id=run_id, worker="w", goal_set_id=goal_set_id,
        checkpoint_file=checkpoint_path(settings.checkpoint_dir, run_id), interrupt=interrupt,
    )  # fmt: skip


def test_interrupt_stops_the_naive_classifier_training_and_the_resume_redoes_it(
    setup: tuple[Settings, Store, int], monkeypatch: pytest.MonkeyPatch
) -> None:
    settings, store, goal_set_id = setup
    config = tiny_config(algorithm="naive_classifier", total_steps=120, naive_classifier_steps=100_000)
    run_id = create_run(store, goal_set_id, config)
    interrupt = threading.Event()
    calls = []
    update = RewardModel.update_classifier

    def counted(model: RewardModel, *args: object, **kwargs: object) -> dict[str, float]:
        calls.append(1)
        if len(calls) == 5:
            interrupt.set()  # Ctrl-C during the 100,000-step training
        return update(model, *args, **kwargs)

    monkeypatch.setattr(RewardModel, "update_classifier", counted)
    runner = _claimed_runner(store, settings, run_id, config, goal_set_id, interrupt)
    try:
        assert train(runner) == Outcome.REQUEUED
    finally:
        runner.close()
    assert len(calls) == 5
    state = load_checkpoint(checkpoint_path(settings.checkpoint_dir, run_id))
    assert state is not None and state["step"] == config.epoch_steps and not state["naive_trained"]
    assert store.get_run(run_id=run_id).status == RunStatus.QUEUED

    calls.clear()
    resumed_config = replace(config, naive_classifier_steps=30)
    runner = _claimed_runner(store, settings, run_id, resumed_config, goal_set_id)
    try:
        assert train(runner) == Outcome.FINISHED
    finally:
        runner.close()
    assert len(calls) == 30  # trained again, in full, once
    final = load_checkpoint(checkpoint_path(settings.checkpoint_dir, run_id))
    assert final is not None and final["naive_trained"]
    assert [m.step for m in store.metrics(run_id=run_id, names=["reward/loss"])] == [config.epoch_steps]


def test_interrupt_stops_an_evaluation(setup: tuple[Settings, Store, int]) -> None:
    settings, store, _ = setup
    config = tiny_config(algorithm="sparse", eval_episodes=5)
    run_id = create_run(store, None, config)
    interrupt = threading.Event()
    runner = _claimed_runner(store, settings, run_id, config, None, interrupt)
    trainer = runner.trainer
    steps = []
    step = trainer.eval_envs[0].step  # (the 5 episodes run in lockstep: the first env's steps are the ticks)

    def counted(action: np.ndarray):
        steps.append(1)
        if len(steps) == 3:
            interrupt.set()
        return step(action)

    trainer.eval_envs[0].step = counted
    try:
        trainer._evaluate()
    finally:
        runner.close()
    assert len(steps) == 3
    assert store.metrics(run_id=run_id) == [] and store.latest_rollout(run_id=run_id) is None
    assert trainer.counters.evaluated_step == -1  # not done: a resume at this step evaluates again


def test_setup_beats_and_a_missing_checkpoint_restarts_with_a_warning(
    setup: tuple[Settings, Store, int], monkeypatch: pytest.MonkeyPatch
) -> None:
    settings, store, goal_set_id = setup
    config = tiny_config(algorithm="vice_raq", heartbeat_seconds=1e-6)
    run_id = create_run(store, goal_set_id, config)
    interrupt = threading.Event()
    runner = _claimed_runner(store, settings, run_id, config, goal_set_id, interrupt)
    assert store.heartbeat(run_id=run_id, worker="w", step=500)  # another host got this far; no checkpoint here
    store.record_metrics(run_id=run_id, step=400, values={"critic/loss": 1.0})
    beats: list[dict] = []
    heartbeat = store.heartbeat

    def recorded(**kwargs: object) -> bool:
        beats.append(dict(kwargs, stored_step=store.get_run(run_id=run_id).step))
        return heartbeat(**kwargs)

    monkeypatch.setattr(store, "heartbeat", recorded)
    interrupt.set()  # stop at the first step
    try:
        assert train(runner) == Outcome.REQUEUED
    finally:
        runner.close()
    first_training = next(i for i, beat in enumerate(beats) if beat.get("status") == RunStatus.TRAINING)
    assert first_training >= 3  # after the goals, the checkpoint read and the restore (and the queries)
    assert beats[0]["step"] is None and beats[1]["stored_step"] == 500  # the stored step is not clobbered
    events = store.events(run_id=run_id, limit=1000)
    warning = [e for e in events if e.level == "warning"]
    assert len(warning) == 1 and "no checkpoint was found at" in warning[0].message
    assert str(checkpoint_path(settings.checkpoint_dir, run_id)) in warning[0].message
    assert "restarts from step 0" in warning[0].message
    assert store.metrics(run_id=run_id, names=["critic/loss"]) == []


def test_goals_are_remade_from_their_originals_at_the_run_image_size(setup: tuple[Settings, Store, int]) -> None:
    settings, store, _ = setup
    rng = np.random.default_rng(0)
    goal_set = store.create_goal_set(name="big", image_size=32)
    originals = []
    for i in range(2):
        pixels = rng.integers(0, 256, size=(64, 80, 3), dtype=np.uint8)  # 80 x 64: centre-cropped to 64 x 64
        original = encode_png(pixels)
        originals.append(pixels)
        model = np.array(Image.fromarray(pixels[:, 8:72]).resize((32, 32), Image.Resampling.LANCZOS))
        store.add_goal_example(
            goal_set_id=goal_set.id, filename=f"g{i}.png", original=original, original_media_type="image/png",
            width=80, height=64, model_png=encode_png(model), display_png=original,
        )  # fmt: skip
    config = tiny_config(algorithm="vice_raq", image_size=16)
    run_id = create_run(store, goal_set.id, config)
    runner = _claimed_runner(store, settings, run_id, config, goal_set.id)
    trainer = runner.trainer
    try:
        trainer.load_goals()
    finally:
        runner.close()
    assert trainer.reward_model is not None
    goals = trainer.reward_model.goals
    assert goals.shape == (2, 16, 16, 3)
    for goal, pixels in zip(goals, originals, strict=True):
        square = Image.fromarray(pixels[:, 8:72])
        expected = np.array(square.resize((16, 16), Image.Resampling.LANCZOS, reducing_gap=3.0))
        np.testing.assert_array_equal(goal, expected)
    # at the goal set's own size the stored model copies are used as they are
    same = tiny_config(algorithm="vice_raq", image_size=32)
    runner = open_runner(
        same, store=store, run_id=run_id, worker="w", goal_set_id=goal_set.id,
        checkpoint_file=checkpoint_path(settings.checkpoint_dir, run_id),
    )  # fmt: skip
    trainer = runner.trainer
    try:
        trainer.load_goals()
    finally:
        runner.close()
    assert trainer.reward_model is not None
    stored = [decode_image(g.model_png, 32) for g in store.goal_images(goal_set_id=goal_set.id)]
    np.testing.assert_array_equal(trainer.reward_model.goals, np.stack(stored))


def _posted_queries(store: Store, goal_set_id: int, config: TrainConfig, checkpoint_file: Path) -> list[tuple]:
    run_id = create_run(store, goal_set_id, config)
    store.claim_next_run(worker="w")
    runner = open_runner(
        config, store=store, run_id=run_id, worker="w", goal_set_id=goal_set_id, checkpoint_file=checkpoint_file
    )
    try:
        assert train(runner) == Outcome.FINISHED
    finally:
        runner.close()
    return [
        (query.env_step, store.query_image(query_id=query.id, resolution="display"), query.info)
        for query in store.list_queries(run_id=run_id, limit=100)
    ]


def test_candidates_scored_in_batches_give_the_queries_scored_one_at_a_time(
    setup: tuple[Settings, Store, int], tmp_path: Path
) -> None:
    """DotReach can snapshot its state: its observations are scored 16 at a time and the kept ones rendered from
    their snapshots; without answers the run is the same, so every query must be the same observation, shown
    with the same display render and info, as when each observation is scored when it is made."""
    _, store, goal_set_id = setup
    one_at_a_time = _posted_queries(store, goal_set_id, tiny_config(query_score_batch=1), tmp_path / "a.pt")
    batched = _posted_queries(store, goal_set_id, tiny_config(query_score_batch=16), tmp_path / "b.pt")
    assert len(one_at_a_time) == tiny_config().query_budget
    assert batched == one_at_a_time


def test_lockstep_evaluation_runs_the_episodes_a_one_by_one_evaluation_runs(setup: tuple[Settings, Store, int]) -> None:
    """11 episodes (groups of 8 and 3 envs): the recorded return and success rate are those of the same seeded
    episodes played one at a time with the same deterministic policy."""
    settings, store, _ = setup
    config = tiny_config(algorithm="sparse", eval_episodes=11)
    run_id = create_run(store, None, config)
    runner = _claimed_runner(store, settings, run_id, config, None)
    trainer = runner.trainer
    try:
        assert len(trainer.eval_envs) == 8
        step = 200
        assert trainer.evaluator.evaluate(step)
        env, space = trainer.episodes[0].env, trainer.action_space
        returns, successes = [], []
        for episode in range(11):
            raw, _ = env.reset(seed=config.seed * 100_003 + 1_000_000 + step + episode)
            obs, total = model_image(raw, config.image_size), 0.0
            for _ in range(config.episode_steps):
                action = trainer.agent.act(obs, deterministic=True)
                raw, reward, terminated, truncated, info = env.step(scale_action(action, space))
                obs, total = model_image(raw, config.image_size), total + float(reward)
                if terminated or truncated:
                    break
            returns.append(total)
            successes.append(float(info["success"]))
    finally:
        runner.close()
    assert len(set(returns)) > 1  # the episodes differ (their seeds)
    recorded = {m.name: m.value for m in store.metrics(run_id=run_id)}
    assert recorded["eval/return"] == pytest.approx(np.mean(returns), abs=1e-6)
    assert recorded["eval/success_rate"] == pytest.approx(np.mean(successes))
    assert store.latest_rollout(run_id=run_id).frame_count == config.episode_steps + 1


def test_several_envs_step_in_lockstep_and_their_states_are_checkpointed(setup: tuple[Settings, Store, int]) -> None:
    """num_envs=3: every env steps (the policy acting for all in one batch), each env step is one loop step, a
    checkpoint step ends the batch early (the control check comes right after it), each env's generator is in the
    checkpoint, and the run finishes at exactly total_steps. Without the update thread a batch's updates follow
    its env steps (with it they overlap: the next test)."""
    settings, store, goal_set_id = setup
    config = tiny_config(algorithm="vice_raq", num_envs=3, total_steps=200, checkpoint_every=100, update_thread="off")
    run_id = create_run(store, goal_set_id, config)
    runner = _claimed_runner(store, settings, run_id, config, goal_set_id)
    trainer = runner.trainer
    steps = [0, 0, 0]
    events = []  # "S" an env step, "U" a step's SAC updates
    for index, episode in enumerate(trainer.episodes):
        original = episode.env.step

        def counted(action: np.ndarray, index: int = index, original=original):
            steps[index] += 1
            events.append("S")
            return original(action)

        episode.env.step = counted
    sac_updates = trainer.sac_updates
    trainer.sac_updates = lambda count: events.append("U" * count) or sac_updates(count)
    batches = []
    act_batch = trainer.agent.act_batch
    trainer.agent.act_batch = lambda observations, deterministic=False, generator=None, noise=None: (
        batches.append(len(observations)) or act_batch(observations, deterministic, generator, noise)
    )
    try:
        assert train(runner) == Outcome.FINISHED
    finally:
        runner.close()
    assert trainer.counters.step == 200 and trainer.replay.added == 200
    assert sum(steps) == 200 and min(steps) >= 60, steps
    assert steps[0] == 68  # the checkpoint at step 100 ended a batch after the first env; the next began with it
    # a batch's envs all step (physics and render) before its steps' updates run, updates_per_step per env step
    runs = re.findall(r"S+|U+", "".join(events))[2:]  # (after the warm-up's steps and the first updates)
    per_step = config.updates_per_step
    assert runs.count("SSS") > 30, runs
    assert all(len(s) * per_step == len(u) for s, u in zip(runs[::2], runs[1::2], strict=True)), runs
    # one forward pass per 3 env steps after the warm-up (the evaluations act on their 2 episodes in one batch)
    assert batches.count(3) >= (200 - config.initial_random_steps) // 3 - 2 and batches.count(2) > 0
    state = load_checkpoint(checkpoint_path(settings.checkpoint_dir, run_id))
    assert len(state["rng"]["envs"]) == 3 and state["rng"]["envs"][0] == state["rng"]["env"]
    assert len({json.dumps(s, default=str) for s in state["rng"]["envs"]}) == 3  # each env its own stream
    assert trainer.replay.frame_capacity == 2 * config.replay_capacity + 2 * 3
    resumed_runner = open_runner(
        config, store=store, run_id=run_id, worker="w2", goal_set_id=goal_set_id,
        checkpoint_file=checkpoint_path(settings.checkpoint_dir, run_id),
    )  # fmt: skip
    resumed = resumed_runner.trainer
    try:
        resumed._restore(state)  # every env continues its own generator, and acting its own
        assert [e.env.unwrapped.np_random.bit_generator.state for e in resumed.episodes] == state["rng"]["envs"]
        assert torch.equal(state["rng"]["acting"], trainer.acting_generator.get_state())
        assert torch.equal(resumed.acting_generator.get_state(), trainer.acting_generator.get_state())
        fresh = torch.Generator().manual_seed(config.seed).get_state()
        assert not torch.equal(fresh, trainer.acting_generator.get_state())  # (it has drawn the actions)
    finally:
        resumed_runner.close()
    other = open_runner(
        replace(config, num_envs=2), store=store, run_id=run_id, worker="w3", goal_set_id=goal_set_id,
        checkpoint_file=checkpoint_path(settings.checkpoint_dir, run_id),
    )  # fmt: skip
    try:
        with pytest.raises(ValueError, match="num_envs changed"):
            other.trainer._restore(state)
    finally:
        other.close()


def test_the_updates_run_on_the_update_thread_while_the_loop_acts_steps_and_scores(
    setup: tuple[Settings, Store, int],
) -> None:
    """update_thread auto on the CPU: each batch's SAC updates run on another thread while the loop's thread acts
    (on a copy of pi synced before the updates: the actions are those of pi as the last batch left it), steps the
    envs and scores the query candidates waiting for a batch; an update waits for the loop to reach that scoring
    in its own batch, which a sequential loop never lets happen. One update per env step after the warm-up, and
    the run learns to its end as without the thread."""
    settings, store, goal_set_id = setup
    config = tiny_config(algorithm="vice_raq", num_envs=2, total_steps=150, query_score_batch=8)
    run_id = create_run(store, goal_set_id, config)
    runner = _claimed_runner(store, settings, run_id, config, goal_set_id)
    trainer = runner.trainer
    assert runner.update_thread is not None and runner.acting_copy is not None
    reached = threading.Event()  # the loop's thread has acted, stepped and scored in this batch
    overlapped, threads, order, scored, same_as_live = [], set(), [], [], []
    for episode in trainer.episodes:
        original = episode.env.step

        def step(action: np.ndarray, original=original):
            order.append("S")
            return original(action)

        episode.env.step = step
    acting_copy = runner.acting_copy
    act_batch = acting_copy.act_batch

    def act(observations: np.ndarray, deterministic: bool = False, noise: torch.Tensor | None = None) -> np.ndarray:
        order.append("A")
        # (this batch's updates wait for the scoring below, so the live pi is still as the last batch left it)
        live = trainer.agent.act_batch(observations, deterministic=True)
        same_as_live.append(np.array_equal(act_batch(observations, deterministic=True), live))
        return act_batch(observations, deterministic, noise)

    acting_copy.act_batch = act
    score_full_batch = trainer.queries.score_full_batch

    def score() -> None:
        order.append("Q")
        pending = len(trainer.queries.pending)
        score_full_batch()
        if pending >= config.query_score_batch and trainer.counters.step >= config.initial_random_steps:
            scored.append(trainer.counters.step)
        reached.set()  # (after the scoring: this batch's updates cannot end before it)

    trainer.queries.score_full_batch = score
    sac_updates = trainer.sac_updates

    def updates(count: int) -> None:
        threads.add(threading.current_thread().name)
        overlapped.append(reached.wait(timeout=5.0))
        sac_updates(count)

    trainer.sac_updates = updates
    step_batch = runner.steps

    def batch(count: int):  # (each batch starts with the loop's thread not yet at the scoring)
        reached.clear()
        return step_batch(count)

    runner.steps = batch
    try:
        assert train(runner) == Outcome.FINISHED
    finally:
        runner.close()
    assert (
        threads
        and threading.current_thread().name not in threads
        and all(name.startswith("sac-updates") for name in threads)
    )
    assert len(overlapped) == 51 and all(overlapped)  # the batches of steps (49, 50) to (149, 150)
    assert "".join(order).count("ASSQ") == 50  # per batch after the warm-up: act, step both envs, score
    assert len(same_as_live) == 50 and all(same_as_live) and acting_copy.actor is not trainer.agent.actor
    assert len(scored) >= 10  # batches of 8 candidates scored while their batch's updates waited
    assert trainer.counters.total_updates == (150 - config.initial_random_steps + 1) * config.updates_per_step
    assert {m.name for m in store.metrics(run_id=run_id)} >= {"critic/loss", "eval/success_rate"}


def test_an_epochs_classifier_trains_on_the_update_thread_while_the_evaluation_runs(
    setup: tuple[Settings, Store, int],
) -> None:
    """With the update thread, at a step that ends an epoch and evaluates (100 here), f_psi's steps run on the
    update thread while the evaluation's episodes run on the loop's thread (each waits for the other to have begun,
    which in a sequential loop times out); f_psi is published once after its steps, and the
    evaluation is recorded after that with the new f_psi (eval/classifier_return)."""
    settings, store, goal_set_id = setup
    config = tiny_config(algorithm="vice_raq", total_steps=100, classifier_steps=3, eval_episodes=1)
    run_id = create_run(store, goal_set_id, config)
    runner = _claimed_runner(store, settings, run_id, config, goal_set_id)
    trainer = runner.trainer
    assert trainer.classifier_thread is runner.update_thread is not None
    model = trainer.reward_model
    classifier_began, evaluation_began = threading.Event(), threading.Event()
    met: list[tuple[str, bool]] = []  # (thread, whether the other had begun) at step 100
    classifier_step = trainer.updates.classifier_step

    def step_of_classifier(**kwargs):
        if trainer.counters.step == 100:
            classifier_began.set()  # (a sequential loop has no evaluation running: the wait times out)
            met.append((threading.current_thread().name, evaluation_began.wait(timeout=5.0)))
        return classifier_step(**kwargs)

    trainer.updates.classifier_step = step_of_classifier
    eval_step = trainer.eval_envs[0].step

    def step_of_evaluation(action: np.ndarray):
        if trainer.counters.step == 100:
            evaluation_began.set()
            met.append((threading.current_thread().name, classifier_began.wait(timeout=5.0)))
        return eval_step(action)

    trainer.eval_envs[0].step = step_of_evaluation
    run_episodes = trainer.evaluator.run_episodes
    versions = []
    trainer.evaluator.run_episodes = lambda step: versions.append(model.version) or run_episodes(step)
    record = trainer.evaluator.record
    recorded = []

    def record_with_version(step, episodes):
        recorded.append((model.version, sum(float(model.logits(np.stack(e.next_obs)).sum()) for e in episodes)))
        return record(step, episodes)

    trainer.evaluator.record = record_with_version
    try:
        assert train(runner) == Outcome.FINISHED
    finally:
        runner.close()
    classifier_threads = {name for name, _ in met if name != threading.current_thread().name}
    assert len(met) == 3 + 25 and all(other_began for _, other_began in met)  # 3 f_psi steps, 25 env steps
    assert len(classifier_threads) == 1 and classifier_threads.pop().startswith("sac-updates")
    assert recorded[-1][0] == versions[-1] + 1  # published once, after its 3 steps and before the record
    metrics = {(m.name, m.step): m.value for m in store.metrics(run_id=run_id)}
    assert metrics[("eval/classifier_return", 100)] == pytest.approx(recorded[-1][1], rel=1e-5)
    assert ("reward/loss", 100) in metrics and ("reward/loss", 50) in metrics


def test_heartbeats_go_on_while_training_work_blocks_the_loop(setup: tuple[Settings, Store, int]) -> None:
    """A classifier epoch that holds the loop's thread for 2.5 s does not silence the learner: its heartbeats come
    from a thread of their own, never more than twice heartbeat_seconds apart, so no other learner takes the run."""
    settings, store, goal_set_id = setup
    config = tiny_config(algorithm="vice_raq", total_steps=100, heartbeat_seconds=0.5)
    run_id = create_run(store, goal_set_id, config)
    runner = _claimed_runner(store, settings, run_id, config, goal_set_id)
    trainer = runner.trainer
    beats: list[float] = []
    heartbeat = store.heartbeat
    store.heartbeat = lambda **kwargs: beats.append(time.monotonic()) or heartbeat(**kwargs)  # type: ignore[method-assign]
    classifier_step = trainer.updates.classifier_step
    blocked: list[float] = []

    def slow_classifier_step(**kwargs):
        if not blocked:
            blocked.append(time.monotonic())
            time.sleep(2.5)  # (a long epoch, a slow disk: the loop's thread does nothing else meanwhile)
        return classifier_step(**kwargs)

    trainer.updates.classifier_step = slow_classifier_step
    try:
        assert train(runner) == Outcome.FINISHED
    finally:
        runner.close()
    assert blocked
    during = [t for t in beats if blocked[0] <= t <= blocked[0] + 2.5]
    assert len(during) >= 3, during
    gaps = np.diff(beats)
    assert gaps.max() <= 2 * config.heartbeat_seconds, gaps.max()
