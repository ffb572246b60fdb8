"""Goals from the robot's own camera, through the API: the list of robot cameras, the live frame, Capture, and the
check of an uploaded photo against the camera. The real stand-in robot served by its own process
(robot/drive/process.py, on a thread here; MuJoCo rendering, MUJOCO_GL=egl by default) and the real SQLite store;
no mocks. The server never opens a camera: without the robot's process there is no frame."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import io
import time
from collections.abc import Iterator
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from conftest import STANDIN, robot_serving
from fastapi.testclient import TestClient
from PIL import Image

from contract.envs import SIM_ENV_IDS
from contract.store import RunStatus, Store
from contract.store.robot_processes import FRAME_IDLE_SECONDS, FRAME_WATCHED_SECONDS


@pytest.fixture
def standin(store: Store, tmp_path: Path) -> Iterator[None]:
    """The stand-in robot's own process, up."""
    with robot_serving(store, STANDIN, tmp_path / "checkpoints"):
        yield


def _png(pixels: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="PNG")
    return buffer.getvalue()


def _pixels(data: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(data)) as image:
        return np.asarray(image.convert("RGB"))


def _frame(client: TestClient, env_id: str = STANDIN) -> bytes:
    response = client.get("/api/cameras/frame", params={"env_id": env_id})
    assert response.status_code == 200, response.text
    return response.content


def _goal_set(client: TestClient, env_id: str | None = STANDIN, image_size: int = 48) -> dict:
    response = client.post("/api/goal-sets", json={"name": f"on the coaster {env_id}", "env_id": env_id,
                                                   "image_size": image_size})  # fmt: skip
    assert response.status_code == 201, response.text
    return response.json()


def _check(client: TestClient, goal_set_id: int, photo: bytes, **params: str) -> dict:
    response = client.post(
        f"/api/goal-sets/{goal_set_id}/photo-check", params=params, files={"file": ("goal.png", photo, "image/png")}
    )
    assert response.status_code == 200, response.text
    return response.json()


def test_the_cameras_are_the_robot_envs_and_the_frame_is_the_whole_4_by_3_picture(
    client: TestClient, standin: None
) -> None:
    listed = client.get("/api/cameras").json()["cameras"]
    env_ids = [camera["env_id"] for camera in listed]
    assert STANDIN in env_ids
    assert "VisualPusher-v0" not in env_ids and not set(SIM_ENV_IDS) & set(env_ids)  # simulated, not a RobotEnv
    assert not any(env_id.endswith("MyArm-v0") for env_id in env_ids)  # robot.template is a file to copy
    camera = next(camera for camera in listed if camera["env_id"] == STANDIN)
    assert camera["robot"] == STANDIN and camera["robot_state"] == "waiting for a learner"

    response = client.get(camera["frame_url"])
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "image/png"
    assert response.headers["cache-control"] == "no-store"
    assert response.headers["x-camera-source"] == f"robot {camera['robot']}"
    frame = _pixels(response.content)
    height, width = frame.shape[:2]
    assert width * 3 == height * 4  # 4:3, grey bands at the sides
    assert (frame[:, :8] == 128).all() and frame[:, width // 2 - 40 : width // 2 + 40].std() > 5


def test_capture_adds_the_frame_as_a_goal_photo_the_model_sees_as_the_robot_would(
    client: TestClient, store: Store, standin: None
) -> None:
    goal_set = _goal_set(client, image_size=40)
    shown = _pixels(_frame(client))
    response = client.post(f"/api/goal-sets/{goal_set['id']}/capture", json={"env_id": STANDIN})
    assert response.status_code == 201, response.text
    example = response.json()
    assert example["source"] == "camera" and example["filename"].startswith("camera-")
    assert (example["width"], example["height"]) == (shown.shape[1], shown.shape[0])
    assert "the model sees the middle 384×384" in example["crop_note"]

    original = _pixels(client.get(example["original_url"]).content)
    np.testing.assert_array_equal(original, shown)  # the whole frame the page showed (the arm did not move)
    model = _pixels(client.get(example["model_url"]).content)
    env = gym.make(STANDIN, image_size=40)
    try:
        np.testing.assert_array_equal(model, env.unwrapped.observe(original))  # as the robot's observations
    finally:
        env.close()
    assert model.shape == (40, 40, 3)
    stored = store.list_goal_examples(goal_set_id=goal_set["id"])
    assert [(e.source, e.original_media_type) for e in stored] == [("camera", "image/png")]
    assert client.get(f"/api/goal-sets/{goal_set['id']}").json()["example_count"] == 1


def test_photo_check_names_each_difference_from_the_camera_and_stores_nothing(
    client: TestClient, store: Store, standin: None
) -> None:
    goal_set = _goal_set(client)
    frame_png = _frame(client)
    frame = _pixels(frame_png)

    square = _check(client, goal_set["id"], _png(np.full((48, 48, 3), (210, 200, 190), np.uint8)))
    assert {"aspect", "size"} <= {warning["kind"] for warning in square["warnings"]}
    assert "square" in square["warnings"][0]["message"] and "4:3" in square["warnings"][0]["message"]
    assert square["camera"]["env_id"] == STANDIN and square["camera"]["source"].startswith("robot ")
    assert (square["camera"]["width"], square["camera"]["height"]) == (frame.shape[1], frame.shape[0])
    assert square["photo"] == {"filename": "goal.png", "width": 48, "height": 48}

    dark = _check(client, goal_set["id"], _png(frame // 8))  # same shape and size, lights off
    kinds = [warning["kind"] for warning in dark["warnings"]]
    assert "colour" in kinds and "aspect" not in kinds and "size" not in kinds
    colour = next(warning["message"] for warning in dark["warnings"] if warning["kind"] == "colour")
    assert "much darker" in colour

    assert _check(client, goal_set["id"], frame_png)["warnings"] == []  # the camera's own frame
    captured = client.post(f"/api/goal-sets/{goal_set['id']}/capture", json={"env_id": STANDIN}).json()
    captured_png = client.get(captured["original_url"]).content
    before = len(store.list_goal_examples(goal_set_id=goal_set["id"]))
    assert _check(client, goal_set["id"], captured_png)["warnings"] == []
    assert len(store.list_goal_examples(goal_set_id=goal_set["id"])) == before == 1  # checks store nothing

    # a set of no robot task compares with nothing, unless a camera is named
    plain = _goal_set(client, env_id=None)
    assert _check(client, plain["id"], frame_png) == {
        "warnings": [], "camera": None, "photo": {"filename": "goal.png", "width": 512, "height": 384},
    }  # fmt: skip
    named = _check(client, plain["id"], _png(frame // 8), env_id=STANDIN)
    assert "colour" in [warning["kind"] for warning in named["warnings"]]
    assert store.list_goal_examples(goal_set_id=plain["id"]) == []

    # an upload through the API is stored as before and says how it differs
    response = client.post(
        f"/api/goal-sets/{goal_set['id']}/examples", files=[("files", ("dark.png", _png(frame // 8), "image/png"))]
    )
    assert response.status_code == 201, response.text
    assert "colour" in [warning["kind"] for warning in response.json()[0]["warnings"]]
    response = client.post(
        f"/api/goal-sets/{plain['id']}/examples", files=[("files", ("dark.png", _png(frame // 8), "image/png"))]
    )
    assert response.status_code == 201 and response.json()[0]["warnings"] == []


def test_an_env_that_is_not_a_robot_camera_is_refused_and_nothing_is_stored(client: TestClient, store: Store) -> None:
    goal_set = _goal_set(client, env_id="VisualPusher-v0")
    photo = _png(np.full((60, 80, 3), 100, np.uint8))
    for env_id in ["VisualPusher-v0", "robot.template:MyArm-v0", "os:system", "not-an-env", "a:b:c"]:
        response = client.get("/api/cameras/frame", params={"env_id": env_id})
        assert response.status_code == 422, (env_id, response.text)
        assert STANDIN in response.json()["detail"][0]["msg"]  # the ids that are cameras
        response = client.post(f"/api/goal-sets/{goal_set['id']}/capture", json={"env_id": env_id})
        assert response.status_code == 422, (env_id, response.text)
        assert response.json()["detail"][0]["loc"] == ["body", "env_id"]
        response = client.post(
            f"/api/goal-sets/{goal_set['id']}/photo-check", params={"env_id": env_id},
            files={"file": ("goal.png", photo, "image/png")},
        )  # fmt: skip
        assert response.status_code == 422, (env_id, response.text)
    assert client.get("/api/cameras/frame").status_code == 422
    assert client.post(f"/api/goal-sets/{goal_set['id']}/capture", json={}).status_code == 422
    assert client.post("/api/goal-sets/999/capture", json={"env_id": STANDIN}).status_code == 404
    assert (
        client.post("/api/goal-sets/999/photo-check", files={"file": ("g.png", photo, "image/png")}).status_code == 404
    )
    bad = client.post(f"/api/goal-sets/{goal_set['id']}/photo-check", files={"file": ("g.png", b"junk", "image/png")})
    assert bad.status_code == 400 and "g.png" in bad.json()["detail"]
    # a simulated task's set: the check has no camera to compare with
    assert _check(client, goal_set["id"], photo)["camera"] is None
    assert store.list_goal_examples(goal_set_id=goal_set["id"]) == []


def test_without_the_robots_process_there_is_no_frame_and_the_page_is_told_how_to_start_it(
    client: TestClient, store: Store, tmp_path: Path
) -> None:
    response = client.get("/api/cameras/frame", params={"env_id": STANDIN})
    assert response.status_code == 409 and f"start `raq robot {STANDIN}`" in response.json()["detail"]
    camera = next(camera for camera in client.get("/api/cameras").json()["cameras"] if camera["env_id"] == STANDIN)
    assert camera["robot"] is None and camera["robot_state"] is None
    preview = client.get("/api/envs/preview", params={"env_id": STANDIN, "size": 48})
    assert preview.status_code == 200 and "no frame to show" in preview.json()["description"]  # a robot env still
    goal_set = _goal_set(client)
    response = client.post(f"/api/goal-sets/{goal_set['id']}/capture", json={"env_id": STANDIN})
    assert response.status_code == 409 and store.list_goal_examples(goal_set_id=goal_set["id"]) == []

    with robot_serving(store, STANDIN, tmp_path / "checkpoints"):
        time.sleep(0.25)  # past the server's last look-up of the store
        first = client.get("/api/cameras/frame", params={"env_id": STANDIN})
        assert first.status_code == 200, first.text
        deadline = time.monotonic() + 5  # a page watches: the robot publishes often
        while (process := store.robot_process_of(env_id=STANDIN)) is not None and not (
            process.watched and process.frame_age_seconds is not None
            and process.frame_age_seconds < FRAME_IDLE_SECONDS / 2
        ):  # fmt: skip
            assert time.monotonic() < deadline, process
            client.get("/api/cameras/frame", params={"env_id": STANDIN})
            time.sleep(FRAME_WATCHED_SECONDS)
    assert store.robot_process_of(env_id=STANDIN) is None  # its row goes with it
    time.sleep(0.25)
    assert client.get("/api/cameras/frame", params={"env_id": STANDIN}).status_code == 409


def test_a_running_actor_on_the_same_robot_is_seen_through_its_published_frame(
    client: TestClient, store: Store, standin: None
) -> None:
    assert _frame(client)  # the robot's process publishes frames
    goal_set = store.create_goal_set(name="actor's", env_id=STANDIN)
    run = store.create_run(env_id=STANDIN, algorithm="vice_raq", config={}, goal_set_id=goal_set.id)
    assert store.claim_next_run(worker="robot host").id == run.id
    store.heartbeat(run_id=run.id, worker="robot host", step=10, status=RunStatus.TRAINING)
    store.report_actor(run_id=run.id, state="waiting for a reset")
    time.sleep(0.25)  # past the last look-up of the store
    response = client.get("/api/cameras/frame", params={"env_id": STANDIN})
    assert response.status_code == 409 and "has published no camera frame yet" in response.json()["detail"]

    published = np.zeros((300, 400, 3), np.uint8)
    published[100:200, 150:250] = (200, 30, 30)
    store.report_actor(run_id=run.id, state="episode 1", frame_png=_png(published))
    time.sleep(0.25)
    response = client.get("/api/cameras/frame", params={"env_id": STANDIN})
    assert response.status_code == 200 and response.headers["x-camera-source"] == f"run {run.id}"
    np.testing.assert_array_equal(_pixels(response.content), published)
    captured = client.post(f"/api/goal-sets/{goal_set.id}/capture", json={"env_id": STANDIN}).json()
    assert (captured["width"], captured["height"], captured["source"]) == (400, 300, "camera")
