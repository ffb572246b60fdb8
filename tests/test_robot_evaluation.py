"""Evaluate now on a robot run: a person asks for episodes with the policy's mean action while the run learns in
real time; the last frame of each becomes a question outside the query budget, and the yes share of the round's
answers is the run's evaluation success rate."""

import functools
import threading
import time

import numpy as np
import pytest
from conftest import create_run, learn_once_beside
from test_actor import real_time_config

from contract.envs import decode_image
from contract.settings import Settings
from contract.store import QueryStatus, RunStatus, Store
from learner.checkpoint import checkpoint_path, load_checkpoint
from learner.robot_evaluation import EVALUATION_STRATEGY, SUCCESS_RATE

EVALUATE_FROM_STEP = 60
"""The person presses Evaluate now once the run is past this step (the warm-up over, the policy acting)."""


@pytest.fixture
def setup(dot_reach: tuple[Settings, Store, int]) -> tuple[Settings, Store, int]:
    return dot_reach


def evaluating_person(store: Store, run_id: int, done: threading.Event, *, evaluation_answers: dict[int, bool]) -> None:
    """A person who presses Ready whenever the actor asks for a reset, presses Evaluate now (2 episodes) once the
    run is past EVALUATE_FROM_STEP, answers the evaluation questions as `evaluation_answers` says (by episode)
    and the learner's own questions truthfully."""
    asked_for_evaluation = False
    while not done.is_set():
        if store.robot_status(run_id=run_id).reset_needed:
            store.scene_ready(run_id=run_id)
        if not asked_for_evaluation and (store.get_run(run_id=run_id).step or 0) >= EVALUATE_FROM_STEP:
            store.request_evaluation(run_id=run_id, episodes=2)
            asked_for_evaluation = True
        for query in store.pending_queries(run_id=run_id):
            if query.strategy == EVALUATION_STRATEGY:
                success = evaluation_answers[query.info["episode"]]
            else:
                success = bool(query.ground_truth_success)
            store.answer_query(query_id=query.id, success=success, labeler="person")
        time.sleep(0.02)


def test_evaluate_now_asks_about_each_episodes_last_frame_and_records_the_yes_share(
    setup: tuple[Settings, Store, int],
) -> None:
    settings, store, goal_set_id = setup
    config = real_time_config(control_hz=100.0)
    run_id = create_run(store, goal_set_id, config)
    person = functools.partial(evaluating_person, store, run_id, evaluation_answers={1: True, 2: False})
    assert learn_once_beside(settings, person) == 0
    run = store.get_run(run_id=run_id)
    assert run.status == RunStatus.FINISHED, run.status_reason
    assert run.step == config.total_steps  # the evaluation's steps are env steps of the run

    queries = store.list_queries(run_id=run_id, oldest_first=True)
    evaluation = [query for query in queries if query.strategy == EVALUATION_STRATEGY]
    assert [query.info for query in evaluation] == [
        {"evaluation_round": 1, "episode": 1},
        {"evaluation_round": 1, "episode": 2},
    ]
    first, second = evaluation
    assert second.env_step - first.env_step >= config.episode_steps  # one episode's last frame each
    for query in evaluation:
        assert query.ground_truth_success in (0.0, 1.0)  # DotReach says whether the dot is on the target
        assert query.status == QueryStatus.ANSWERED and query.used_at is not None  # the learner read the answer
    # the query budget is the learner's own questions': evaluation questions do not count against it
    assert len(queries) - len(evaluation) == config.query_budget
    assert store.robot_status(run_id=run_id).evaluation_pending == 0

    # the round's success rate: one yes of two, at the step its first episode began
    [rate] = store.metrics(run_id=run_id, names=[SUCCESS_RATE])[-1:]
    assert rate.value == 0.5
    assert rate.step == first.env_step - config.episode_steps
    assert rate.step >= EVALUATE_FROM_STEP

    # the yes joined the classifier's positives (the no did not)
    state = load_checkpoint(checkpoint_path(settings.checkpoint_dir, run_id))
    assert state is not None
    positives = state["reward_model"]["answered_positives"].numpy()
    yes_image = decode_image(store.query_image(query_id=first.id, resolution="model"), config.image_size)
    no_image = decode_image(store.query_image(query_id=second.id, resolution="model"), config.image_size)
    assert any(np.array_equal(positive, yes_image) for positive in positives)
    assert not any(np.array_equal(positive, no_image) for positive in positives)
    messages = [event.message for event in store.events(run_id=run_id, limit=1000)]
    assert "evaluate now: round 1, 2 episodes with the policy's mean action" in messages
    assert any(message.startswith("evaluation round 1: 1 of 2 answered yes") for message in messages)
