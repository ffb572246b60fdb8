"""The verdict on a run's reward: from recorded runs (a stuck door run, a learning pusher run, a robot run still in
its warm-up), its rules one by one, and the API and run page that show it."""

import io
import json
from pathlib import Path

from fastapi.testclient import TestClient
from PIL import Image

from contract.reward_health import AnsweredQuestion, reward_verdict
from contract.store import Store

DATA = Path(__file__).parent / "recorded"
AFTER_WARM_UP = 5000
"""An env step after the default warm-up (initial_random_steps 1000)."""


def recorded(name: str, *, upto_step: int | None = None) -> tuple[list[AnsweredQuestion], list[tuple[int, float]]]:
    """A recorded run's answers (their order) and eval success; the asked states' f_psi scores and env steps were
    not recorded, so they are given as not rated a success and asked after the warm-up."""
    run = json.loads((DATA / name).read_text())
    success = [(step, rate) for step, rate in run["success_rate"] if upto_step is None or step <= upto_step]
    answered = [AnsweredQuestion(env_step=AFTER_WARM_UP, score=-1.0, answer=answer) for answer in run["answers"]]
    return answered, success


def test_a_stuck_run_is_called_stuck_with_what_to_do() -> None:
    answered, success = recorded("reward_health_door_stuck.json")
    flat_return = [(step, 0.0) for step, _ in success]
    verdict = reward_verdict(answered=answered, success_rate=success, classifier_return=flat_return)
    assert verdict.level == "stuck"
    assert "none of the last 10 asked states was a success" in verdict.summary
    assert "has not reached the goal" in verdict.summary and verdict.advice
    assert verdict.asks_for_help and "take over on the run page" in verdict.advice  # a person's hands would help


def test_a_learning_run_is_called_learning_before_and_after_it_reaches_its_target() -> None:
    answered, success = recorded("reward_health_pusher_learning.json")
    assert reward_verdict(answered=answered, success_rate=success).level == "learning"
    assert not reward_verdict(answered=answered, success_rate=success).asks_for_help
    early = [(step, rate) for step, rate in success if step <= 12_000]
    verdict = reward_verdict(answered=answered[:2], success_rate=early)
    assert verdict.level == "learning" and not verdict.advice


def test_states_rated_successes_and_all_answered_no_mean_the_classifier_is_exploited() -> None:
    answered = [AnsweredQuestion(env_step=AFTER_WARM_UP + i, score=2.0 + i / 10, answer=False) for i in range(12)]
    verdict = reward_verdict(answered=answered)
    assert verdict.level == "stuck"
    assert verdict.summary.startswith("f_psi rated each of the last 10 asked states a success (p > 0.5) and all were")
    assert "no_answer_share" in verdict.advice
    # one yes among them: not the exploitation verdict
    answered[-1] = AnsweredQuestion(env_step=AFTER_WARM_UP + 11, score=2.0, answer=True)
    assert not reward_verdict(answered=answered).summary.startswith("f_psi rated")


def test_low_agreement_with_the_answers_points_at_the_goal_photos() -> None:
    answered = [AnsweredQuestion(env_step=AFTER_WARM_UP + i, score=-1.0, answer=i % 2 == 0) for i in range(8)]
    verdict = reward_verdict(answered=answered, agreement=[(1000, 0.9), (2000, 0.4)])
    assert verdict.level == "stuck" and "agrees with only 40%" in verdict.summary
    assert "Framing" in verdict.advice


def test_no_yes_yet_with_a_classifier_return_still_moving_is_a_warning_not_stuck() -> None:
    answered = [AnsweredQuestion(env_step=AFTER_WARM_UP + i, score=-1.0, answer=False) for i in range(4)]
    rising = [(1000 * i, float(i)) for i in range(8)]
    assert reward_verdict(answered=answered, classifier_return=rising).level == "watch"
    assert reward_verdict(answered=[]).level == "too early"


def robot_warm_up_run() -> tuple[dict, list[AnsweredQuestion]]:
    """The robot run 1,500 env steps in, its three answered questions all about warm-up states."""
    run = json.loads((DATA / "reward_health_robot_warm_up.json").read_text())
    return run, [AnsweredQuestion(**question) for question in run["answered"]]


def test_a_robot_run_whose_answers_are_all_about_its_warm_up_is_too_early_to_judge() -> None:
    run, answered = robot_warm_up_run()
    return_curve = [(step, value) for step, value in run["classifier_return"]]
    verdict = reward_verdict(
        answered=answered, classifier_return=return_curve, warm_up_steps=run["initial_random_steps"]
    )
    assert verdict.level == "too early", verdict
    assert "exploiting" not in verdict.summary and not verdict.advice
    assert "the 3 answers so far are about the warm-up's random states (up to step 1,000)" in verdict.summary


def test_a_state_the_pages_show_as_p_50_percent_is_not_rated_a_success() -> None:
    run, answered = robot_warm_up_run()
    later = [AnsweredQuestion(env_step=q.env_step + 1000, score=q.score, answer=q.answer) for q in answered]
    assert [round(100 * q.probability) for q in later] == [64, 50, 50]
    assert [q.rated_success for q in later] == [True, False, False]
    verdict = reward_verdict(answered=later, warm_up_steps=run["initial_random_steps"])
    assert "exploiting" not in verdict.summary and verdict.level == "watch"
    assert "none of the last 3 asked states was a success" in verdict.summary
    # the same answers, with f_psi giving each p > 0.5: now they are rated successes
    rated = [AnsweredQuestion(env_step=q.env_step, score=0.5, answer=False) for q in later]
    verdict = reward_verdict(answered=rated, warm_up_steps=run["initial_random_steps"])
    assert verdict.summary.startswith("f_psi rated each of the last 3 asked states a success (p > 0.5)")


def test_eval_success_in_the_warm_up_is_not_evidence_of_learning() -> None:
    random_success = [(500, 1.0), (1000, 1.0)]
    assert reward_verdict(answered=[], success_rate=random_success, warm_up_steps=1000).level == "too early"
    assert reward_verdict(answered=[], success_rate=[*random_success, (2000, 0.95)], warm_up_steps=1000).level == (
        "learning"
    )


def _png(shade: int, size: int) -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (size, size), (shade, shade, 0)).save(buffer, format="PNG")
    return buffer.getvalue()


def test_the_api_gives_the_verdict(client: TestClient, store: Store, goal_set_with_photo: dict) -> None:
    run = client.post("/api/runs", json={"env_id": "VisualPusher-v0", "goal_set_id": goal_set_with_photo["id"]}).json()
    assert client.get(f"/api/runs/{run['id']}/reward-health").json()["level"] == "too early"
    for step in range(1, 11):
        query = store.post_query(
            run_id=run["id"], env_step=1000 + 250 * step, model_png=_png(step, 48), display_png=_png(step, 64),
            score=3.0,
        )  # fmt: skip
        store.answer_query(query_id=query.id, success=False)
    health = client.get(f"/api/runs/{run['id']}/reward-health").json()
    assert health["level"] == "stuck" and health["answered"] == 10 and health["asks_for_help"] is True
    assert "exploiting the classifier" in health["summary"]
    store.report_actor(run_id=run["id"], state="acting")  # a robot run: its card says it too
    assert client.get(f"/api/runs/{run['id']}").json()["robot"]["asks_for_help"] is True
    assert client.get(f"/api/runs/{run['id']}/robot").json()["asks_for_help"] is True
    assert client.get("/api/runs/999999/reward-health").status_code == 404


def test_the_api_leaves_out_the_runs_warm_up(client: TestClient, store: Store, goal_set_with_photo: dict) -> None:
    """The recorded robot run's questions, asked in the warm-up of a run whose warm-up is 1,000 steps."""
    recorded_run, answered = robot_warm_up_run()
    config = {"initial_random_steps": recorded_run["initial_random_steps"], "query_every": 250}
    run = client.post(
        "/api/runs", json={"env_id": "VisualPusher-v0", "goal_set_id": goal_set_with_photo["id"], "config": config}
    ).json()
    for number, question in enumerate(answered):
        query = store.post_query(
            run_id=run["id"], env_step=question.env_step, model_png=_png(number, 48), display_png=_png(number, 64),
            score=question.score,
        )  # fmt: skip
        store.answer_query(query_id=query.id, success=question.answer)
    health = client.get(f"/api/runs/{run['id']}/reward-health").json()
    assert health["level"] == "too early" and health["answered"] == 0 and health["warm_up_steps"] == 1000
    assert "exploiting" not in health["summary"] and "warm-up" in health["summary"]
