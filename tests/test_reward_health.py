"""The verdict on a run's reward: from recorded runs (a stuck door run, a learning pusher run), its rules one by one,
and the API and run page that show it."""

import io
import json
from pathlib import Path

from fastapi.testclient import TestClient
from PIL import Image

from contract.reward_health import AnsweredQuestion, reward_verdict
from contract.store import Store

DATA = Path(__file__).parent / "recorded"


def recorded(name: str, *, upto_step: int | None = None) -> tuple[list[AnsweredQuestion], list[tuple[int, float]]]:
    """A recorded run's answers (their order) and eval success; the asked states' f_psi scores were not recorded,
    so they are given as not rated a success."""
    run = json.loads((DATA / name).read_text())
    success = [(step, rate) for step, rate in run["success_rate"] if upto_step is None or step <= upto_step]
    return [AnsweredQuestion(score=-1.0, answer=answer) for answer in run["answers"]], success


def test_a_stuck_run_is_called_stuck_with_what_to_do() -> None:
    answered, success = recorded("reward_health_door_stuck.json")
    flat_return = [(step, 0.0) for step, _ in success]
    verdict = reward_verdict(answered=answered, success_rate=success, classifier_return=flat_return)
    assert verdict.level == "stuck"
    assert "none of the last 10 asked states was a success" in verdict.summary
    assert "has not reached the goal" in verdict.summary and verdict.advice


def test_a_learning_run_is_called_learning_before_and_after_it_reaches_its_target() -> None:
    answered, success = recorded("reward_health_pusher_learning.json")
    assert reward_verdict(answered=answered, success_rate=success).level == "learning"
    early = [(step, rate) for step, rate in success if step <= 12_000]
    verdict = reward_verdict(answered=answered[:2], success_rate=early)
    assert verdict.level == "learning" and not verdict.advice


def test_states_rated_successes_and_all_answered_no_mean_the_classifier_is_exploited() -> None:
    answered = [AnsweredQuestion(score=2.0 + i / 10, answer=False) for i in range(12)]
    verdict = reward_verdict(answered=answered)
    assert verdict.level == "stuck"
    assert verdict.summary.startswith("f_psi rated the last 10 asked states as successes and all were answered no")
    assert "no_answer_share" in verdict.advice
    # one yes among them: not the exploitation verdict
    answered[-1] = AnsweredQuestion(score=2.0, answer=True)
    assert not reward_verdict(answered=answered).summary.startswith("f_psi rated")


def test_low_agreement_with_the_answers_points_at_the_goal_photos() -> None:
    answered = [AnsweredQuestion(score=-1.0, answer=i % 2 == 0) for i in range(8)]
    verdict = reward_verdict(answered=answered, agreement=[(1000, 0.9), (2000, 0.4)])
    assert verdict.level == "stuck" and "agrees with only 40%" in verdict.summary
    assert "Framing" in verdict.advice


def test_no_yes_yet_with_a_classifier_return_still_moving_is_a_warning_not_stuck() -> None:
    answered = [AnsweredQuestion(score=-1.0, answer=False) for _ in range(4)]
    rising = [(1000 * i, float(i)) for i in range(8)]
    assert reward_verdict(answered=answered, classifier_return=rising).level == "watch"
    assert reward_verdict(answered=[]).level == "too early"


def _png(shade: int, size: int) -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (size, size), (shade, shade, 0)).save(buffer, format="PNG")
    return buffer.getvalue()


def test_the_api_gives_the_verdict(client: TestClient, store: Store, goal_set_with_photo: dict) -> None:
    run = client.post("/api/runs", json={"env_id": "VisualPusher-v0", "goal_set_id": goal_set_with_photo["id"]}).json()
    assert client.get(f"/api/runs/{run['id']}/reward-health").json()["level"] == "too early"
    for step in range(1, 11):
        query = store.post_query(
            run_id=run["id"], env_step=1000 * step, model_png=_png(step, 48), display_png=_png(step, 64), score=3.0
        )
        store.answer_query(query_id=query.id, success=False)
    health = client.get(f"/api/runs/{run['id']}/reward-health").json()
    assert health["level"] == "stuck" and health["answered"] == 10
    assert "exploiting the classifier" in health["summary"]
    assert client.get("/api/runs/999999/reward-health").status_code == 404
