"""Queries: listing, the queue's next item, images, answer (idempotent, 409 on a different answer), skip, undo."""

import io

from fastapi.testclient import TestClient
from PIL import Image

from contract.store import Store


def _png(size: int, shade: int) -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (size, size), (shade, shade, 0)).save(buffer, format="PNG")
    return buffer.getvalue()


def _run_with_query(client: TestClient, store: Store, goal_set_id: int, **query: object) -> tuple[int, int]:
    run = client.post("/api/runs", json={"env_id": "VisualPusher-v0", "goal_set_id": goal_set_id}).json()
    posted = store.post_query(
        run_id=run["id"], env_step=query.pop("env_step", 2000), model_png=_png(48, 10), display_png=_png(256, 10),
        score=query.pop("score", 1.5), info={"distance": 0.02}, **query,
    )  # fmt: skip
    return run["id"], posted.id


def test_list_next_and_images(client: TestClient, store: Store, goal_set_with_photo: dict) -> None:
    run_id, query_id = _run_with_query(client, store, goal_set_with_photo["id"], ground_truth_success=1.0)
    second = store.post_query(run_id=run_id, env_step=4000, model_png=_png(48, 5), display_png=_png(256, 5), score=-2)
    pending = client.get("/api/queries", params={"run_id": run_id, "status": "pending"}).json()
    assert [q["id"] for q in pending] == [query_id, second.id]  # oldest first: the order to answer
    first = pending[0]
    assert first["score"] == 1.5 and 0.81 < first["probability"] < 0.82
    assert first["info"] == {"distance": 0.02} and first["ground_truth_success"] == 1.0
    assert client.get("/api/queries", params={"status": "bogus"}).status_code == 422

    item = client.get("/api/queries/next", params={"run_id": run_id}).json()
    assert item["query"]["id"] == query_id and item["pending"] == 2 and item["pending_all_runs"] == 2
    assert item["run"]["id"] == run_id
    assert [e["filename"] for e in item["goal_examples"]] == ["goal.png"]

    model = client.get(f"/api/queries/{query_id}/image", params={"resolution": "model"})
    assert model.status_code == 200 and Image.open(io.BytesIO(model.content)).size == (48, 48)
    display = client.get(first["display_image_url"])
    assert Image.open(io.BytesIO(display.content)).size == (256, 256)
    assert client.get(f"/api/queries/{query_id}/image", params={"resolution": "/etc/passwd"}).status_code == 422
    assert client.get("/api/queries/999/image").status_code == 404
    assert client.get("/api/queries/999").status_code == 404
    assert client.get("/api/queries/next", params={"run_id": 999}).status_code == 404


def test_answer_is_idempotent_and_a_different_one_conflicts(
    client: TestClient, store: Store, goal_set_with_photo: dict
) -> None:
    run_id, query_id = _run_with_query(client, store, goal_set_with_photo["id"])
    response = client.post(f"/api/queries/{query_id}/answer", json={"success": True, "labeler": "ana"})
    assert response.status_code == 200
    assert response.json()["status"] == "answered" and response.json()["answer"] is True
    assert response.json()["labeler"] == "ana"
    again = client.post(f"/api/queries/{query_id}/answer", json={"success": True, "labeler": "ana"})
    assert again.status_code == 200
    conflict = client.post(f"/api/queries/{query_id}/answer", json={"success": False})
    assert conflict.status_code == 409
    assert "already answered" in conflict.json()["detail"]
    assert store.get_query(query_id=query_id).answer is True  # the first answer is kept
    assert client.post(f"/api/queries/{query_id}/skip").status_code == 409
    assert client.post("/api/queries/999/answer", json={"success": True}).status_code == 404
    assert client.post(f"/api/queries/{query_id}/answer", json={"success": "maybe"}).status_code == 422
    counts = client.get(f"/api/runs/{run_id}").json()["queries"]
    assert counts == {"asked": 1, "pending": 0, "answered": 1, "yes": 1, "skipped": 0}
    assert client.get("/api/queries/next").json()["query"] is None


def test_undo_until_the_learner_uses_the_answer(client: TestClient, store: Store, goal_set_with_photo: dict) -> None:
    run_id, query_id = _run_with_query(client, store, goal_set_with_photo["id"])
    assert client.post(f"/api/queries/{query_id}/undo").status_code == 409  # nothing to undo yet
    client.post(f"/api/queries/{query_id}/answer", json={"success": False})
    undone = client.post(f"/api/queries/{query_id}/undo")
    assert undone.status_code == 200 and undone.json()["status"] == "pending" and undone.json()["answer"] is None
    # after an undo a different answer is fine
    assert client.post(f"/api/queries/{query_id}/answer", json={"success": True}).status_code == 200
    used = store.new_answers(run_id=run_id)  # the learner reads it into its classifier
    assert [answer.query_id for answer in used] == [query_id]
    assert client.get(f"/api/queries/{query_id}").json()["used_by_learner"] is True
    late = client.post(f"/api/queries/{query_id}/undo")
    assert late.status_code == 409 and "already used" in late.json()["detail"]
    assert store.get_query(query_id=query_id).answer is True
    assert client.post("/api/queries/999/undo").status_code == 404


def test_skip_then_undo_or_answer(client: TestClient, store: Store, goal_set_with_photo: dict) -> None:
    _run_id, query_id = _run_with_query(client, store, goal_set_with_photo["id"])
    skipped = client.post(f"/api/queries/{query_id}/skip", json={"labeler": "bo"})
    assert skipped.status_code == 200 and skipped.json()["status"] == "skipped"
    assert client.get("/api/queries", params={"status": "pending"}).json() == []
    assert client.post(f"/api/queries/{query_id}/undo").json()["status"] == "pending"
    client.post(f"/api/queries/{query_id}/skip")
    answered = client.post(f"/api/queries/{query_id}/answer", json={"success": True})  # a skipped one can be answered
    assert answered.status_code == 200 and answered.json()["status"] == "answered"


def test_events_of_a_run(client: TestClient, store: Store, goal_set_with_photo: dict) -> None:
    run_id, query_id = _run_with_query(client, store, goal_set_with_photo["id"])
    store.record_event(run_id=run_id, message="evaluating", level="info")
    events = client.get(f"/api/runs/{run_id}/events").json()
    assert events[0]["message"] == "evaluating"  # newest first
    newest = events[0]["id"]
    assert client.get(f"/api/runs/{run_id}/events", params={"since_id": newest}).json() == []
    assert client.get("/api/runs/999/events").status_code == 404
    assert client.get("/queue").status_code == 200 and client.get(f"/queue?run={run_id}").status_code == 200
    assert client.get("/queue?run=999").status_code == 404
