"""A goal photo from another viewpoint than the set's other photos is flagged as such, not only as brighter:
photos of the pusher's scene rendered by MuJoCo from its task camera (the side) and from a camera straight above,
checked through the API against a real SQLite store."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import io

import mujoco
import numpy as np
from fastapi.testclient import TestClient
from PIL import Image

from contract.store import Store
from sim.goals import pusher_success_state
from sim.pusher import VisualPusherEnv

SIDE = 256


def _png(pixels: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="PNG")
    return buffer.getvalue()


def _photos(count: int) -> tuple[list[bytes], list[bytes]]:
    """`count` successes of the pusher, each seen from the task camera (the side) and from straight above."""
    env = VisualPusherEnv(image_size=48, render_size=SIDE)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    above = mujoco.MjvCamera()
    above.type = mujoco.mjtCamera.mjCAMERA_FREE
    above.lookat[:], above.distance, above.azimuth, above.elevation = (0.0, 0.0, 0.0), 0.9, 90.0, -90.0
    renderer = mujoco.Renderer(env.model, SIDE, SIDE)
    side, top = [], []
    try:
        for _ in range(count):
            pusher_success_state(env, rng)
            mujoco.mj_forward(env.model, env.data)
            side.append(_png(env.render_image(SIDE)))
            renderer.update_scene(env.data, camera=above)
            top.append(_png(renderer.render()))
    finally:
        renderer.close()
        env.close()
    return side, top


def _brighter(png: bytes) -> bytes:
    pixels = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.float64)
    return _png(np.clip(pixels * 1.5 + 40, 0, 255).astype(np.uint8))


def _check(client: TestClient, goal_set_id: int, name: str, png: bytes) -> list[dict]:
    response = client.post(f"/api/goal-sets/{goal_set_id}/photo-check", files={"file": (name, png, "image/png")})
    assert response.status_code == 200, response.text
    return response.json()["warnings"]


def test_a_top_down_photo_among_side_photos_is_flagged_as_another_viewpoint(client: TestClient, store: Store) -> None:
    side, top = _photos(7)
    goal_set = client.post("/api/goal-sets", json={"name": "mug on the coaster"}).json()
    uploaded = client.post(
        f"/api/goal-sets/{goal_set['id']}/examples",
        files=[("files", (f"side-{i}.png", png, "image/png")) for i, png in enumerate(side[:5])],
    )
    assert uploaded.status_code == 201 and all(example["warnings"] == [] for example in uploaded.json())

    from_above = _check(client, goal_set["id"], "top.png", top[0])
    assert [warning["kind"] for warning in from_above] == ["viewpoint"], from_above
    assert from_above[0]["message"].startswith("Another viewpoint: the photo's edges and shapes are unlike")
    assert "set's 5 other photos" in from_above[0]["message"]
    # another side photo, and a much brighter one: the same viewpoint
    assert _check(client, goal_set["id"], "side.png", side[5]) == []
    assert _check(client, goal_set["id"], "bright.png", _brighter(side[6])) == []

    # uploaded, the top-down photo carries the warning and is stored all the same
    stored = client.post(
        f"/api/goal-sets/{goal_set['id']}/examples", files=[("files", ("top.png", top[1], "image/png"))]
    ).json()
    assert [warning["kind"] for warning in stored[0]["warnings"]] == ["viewpoint"]
    assert len(store.list_goal_examples(goal_set_id=goal_set["id"])) == 6

    # a set of two photos is too few to tell a viewpoint from
    small = client.post("/api/goal-sets", json={"name": "two photos"}).json()
    client.post(
        f"/api/goal-sets/{small['id']}/examples",
        files=[("files", (f"side-{i}.png", png, "image/png")) for i, png in enumerate(side[:2])],
    )
    assert _check(client, small["id"], "top.png", top[0]) == []
