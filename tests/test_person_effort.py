"""What a run has cost the person, counted from the store's timestamps: answers and the time from a question's
first showing on a page to its answer (each capped), scene resets and the robot's wait for them, and the
person's minutes in all; through GET /api/runs/{id} on real SQLite, and on the bench scripts' columns."""

import io
import time
from datetime import UTC, datetime, timedelta

from fastapi.testclient import TestClient
from PIL import Image

from app.migrate import upgrade
from contract.effort import ANSWER_CAP_SECONDS, EFFORT_COLUMNS, RESET_CAP_SECONDS, person_effort, run_effort
from contract.store import Store


def _png() -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (48, 48), (90, 40, 0)).save(buffer, format="PNG")
    return buffer.getvalue()


def test_the_run_counts_answers_answering_time_and_resets(
    client: TestClient, store: Store, goal_set_with_photo: dict
) -> None:
    run = client.post("/api/runs", json={"env_id": "VisualPusher-v0", "goal_set_id": goal_set_with_photo["id"]}).json()
    assert run["effort"] == {
        "answers": 0, "answer_seconds": 0.0, "resets": 0, "reset_wait_seconds": 0.0, "takeovers": 0,
        "takeover_seconds": 0.0, "person_minutes": 0.0,
    }  # fmt: skip
    first, second = (
        store.post_query(run_id=run["id"], env_step=step, model_png=_png(), display_png=_png(), score=0.0)
        for step in (2000, 3000)
    )
    # a page is served the first question, the person looks at it and answers; serving it again does not restart
    # the clock
    assert client.get(f"/api/queries/next?run_id={run['id']}").json()["query"]["id"] == first.id
    time.sleep(0.4)
    assert client.get(f"/api/queries/next?run_id={run['id']}").json()["query"]["id"] == first.id
    time.sleep(0.4)
    assert client.post(f"/api/queries/{first.id}/answer", json={"success": False}).status_code == 200
    # the second is answered through the API, no page shown it: an answer, no person time
    assert client.post(f"/api/queries/{second.id}/answer", json={"success": True}).status_code == 200

    # the actor asks for a scene reset, the person presses Ready after a while
    store.request_scene_reset(run_id=run["id"])
    store.request_scene_reset(run_id=run["id"])  # (asked again while it waits: one reset)
    time.sleep(0.5)
    assert client.post(f"/api/runs/{run['id']}/robot/ready").status_code == 200
    store.request_scene_reset(run_id=run["id"])  # the next one, still waiting: not counted yet

    effort = client.get(f"/api/runs/{run['id']}").json()["effort"]
    assert effort["answers"] == 2 and effort["resets"] == 1
    assert 0.7 <= effort["answer_seconds"] < 5.0, effort
    assert 0.4 <= effort["reset_wait_seconds"] < 5.0, effort
    assert abs(effort["person_minutes"] - (effort["answer_seconds"] + effort["reset_wait_seconds"]) / 60) < 1e-6
    # the bench scripts' columns, from the same store
    columns = run_effort(store, run["id"]).columns()
    assert list(columns) == list(EFFORT_COLUMNS) == [
        "person_minutes", "answers", "answer_seconds", "resets", "reset_wait_seconds", "takeovers", "takeover_seconds",
    ]  # fmt: skip
    assert columns["answers"] == 2 and columns["resets"] == 1


def test_a_question_left_open_in_an_idle_tab_counts_no_more_than_the_cap() -> None:
    start = datetime(2026, 1, 1, tzinfo=UTC)
    answers = [(start, start + timedelta(seconds=12)), (start, start + timedelta(hours=3)), (None, start)]
    resets = [(start, start + timedelta(seconds=30)), (start, start + timedelta(minutes=20)), (start, None)]
    effort = person_effort(answers, resets)
    assert effort.answers == 3 and effort.answer_seconds == 12 + ANSWER_CAP_SECONDS
    assert effort.resets == 2 and effort.reset_wait_seconds == 30 + 20 * 60  # the robot's wait, whole
    assert effort.person_minutes == (12 + ANSWER_CAP_SECONDS + 30 + RESET_CAP_SECONDS) / 60


def test_the_effort_is_counted_on_postgresql(postgres_url: str) -> None:
    upgrade(postgres_url)
    store = Store(postgres_url)
    try:
        run = store.create_run(env_id="VisualPusher-v0", algorithm="vice_raq", config={"seed": 1})
        query = store.post_query(run_id=run.id, env_step=2000, model_png=_png(), display_png=_png(), score=0.0)
        store.mark_query_shown(query_id=query.id)
        time.sleep(0.3)
        store.mark_query_shown(query_id=query.id)
        store.answer_query(query_id=query.id, success=True)
        store.request_scene_reset(run_id=run.id)
        time.sleep(0.3)
        store.scene_ready(run_id=run.id)
        effort = run_effort(store, run.id)
        assert effort.answers == 1 and effort.resets == 1
        assert 0.25 <= effort.answer_seconds < 5 and 0.25 <= effort.reset_wait_seconds < 5, effort
    finally:
        store.dispose()
