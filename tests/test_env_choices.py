"""Only runs that can work start: the New run form suggests only envs with image observations (the simulated tasks
and the allowed modules' envs whose preview works), a run of an env whose preview fails (no image observations, a
missing dependency) is refused in the form and the API with that reason, and one canonical env id is stored: an id
a fresh learner with the same allow-list could not make is refused, whatever this server imported before."""

from collections.abc import Callable

import httpx
from conftest import LiveServer
from fastapi.testclient import TestClient

from contract.envs import SIM_ENV_IDS

DOT = "learner.testing_envs:DotReach-v0"


def test_the_new_run_form_suggests_only_envs_with_image_observations(client: TestClient) -> None:
    envs = client.get("/api/envs").json()
    assert envs["simulated"] == list(SIM_ENV_IDS)
    assert DOT in envs["registered"]
    assert "CartPole-v1" not in envs["registered"] and "Pusher-v5" not in envs["registered"]
    for bad in ("VisualNaN-v0", "VisualHuge-v0", "VisualText-v0", "VisualGray-v0"):  # bad from the first frame
        assert f"learner.testing_envs:{bad}" not in envs["registered"]
    for env_id in envs["registered"]:  # every suggestion previews
        assert client.get("/api/envs/preview", params={"env_id": env_id}).status_code == 200, env_id
    page = client.get("/runs/new")
    assert page.status_code == 200 and DOT in page.text
    assert "CartPole-v1" not in page.text and "MountainCar" not in page.text


def test_a_run_of_an_env_without_image_observations_is_refused_with_the_reason(client: TestClient) -> None:
    preview = client.get("/api/envs/preview", params={"env_id": "CartPole-v1"})
    assert preview.status_code == 422
    assert preview.json()["detail"][0]["msg"].startswith("CartPole-v1: observation has shape (4,), not an RGB image")
    created = client.post("/api/runs", json={"env_id": "CartPole-v1", "algorithm": "sparse"})
    assert created.status_code == 422
    assert "CartPole-v1: observation has shape (4,), not an RGB image" in created.json()["detail"][0]["msg"]
    assert client.get("/api/runs").json() == []


def test_a_run_of_an_env_whose_preview_fails_is_not_created(client: TestClient) -> None:
    """An env that cannot be made here (a module it needs is missing, as Pusher-v5 without imageio)."""
    env_id = "learner.testing_envs:VisualNeedsMissingModule-v0"
    missing = "No module named 'a_module_that_is_not_installed'"
    preview = client.get("/api/envs/preview", params={"env_id": env_id})
    assert preview.status_code == 422 and missing in preview.text
    created = client.post("/api/runs", json={"env_id": env_id, "algorithm": "sparse"})
    assert created.status_code == 422 and missing in created.text
    assert client.get("/api/runs").json() == []


def test_only_the_id_a_fresh_learner_can_make_is_accepted(make_live_server: Callable[..., LiveServer]) -> None:
    server = make_live_server(RAQ_ENV_MODULES="learner.testing_envs")
    with httpx.Client(base_url=server.url, timeout=60) as client:
        assert client.get("/api/envs/preview", params={"env_id": DOT}).status_code == 200  # imports the module here
        bare = client.post("/api/runs", json={"env_id": "DotReach-v0", "algorithm": "sparse"})
        assert bare.status_code == 422, bare.text
        assert f"name it {DOT}" in bare.json()["detail"][0]["msg"]
        assert client.get("/api/envs/preview", params={"env_id": "DotReach-v0"}).status_code == 422
        elsewhere = client.post("/api/runs", json={"env_id": "sim:DotReach-v0", "algorithm": "sparse"})
        assert elsewhere.status_code == 422 and "importing 'sim' does not register 'DotReach-v0'" in elsewhere.text
        assert client.get("/api/runs").json() == []
        canonical = client.post("/api/runs", json={"env_id": DOT, "algorithm": "sparse"})
        assert canonical.status_code == 201, canonical.text
        assert canonical.json()["env_id"] == DOT
