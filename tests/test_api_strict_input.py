"""The API reads its input as it is written: a count is a JSON integer and a switch is true or false (anything else
is a 422 that changes nothing), an id in a path is digits, a 405 names every method of its path, expensive reads
(previews, images, exports) are refused to other sites' pages, and previews keep the server's memory bounded under
80 callers at once."""

import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest
from conftest import LiveServer
from fastapi.testclient import TestClient

from app.previews import PREVIEW_SIZES
from contract.store import Store

CROSS_SITE = {"Sec-Fetch-Site": "cross-site"}


@pytest.fixture
def run_id(client: TestClient, goal_set_with_photo: dict) -> int:
    created = client.post("/api/runs", json={"env_id": "VisualPusher-v0", "goal_set_id": goal_set_with_photo["id"]})
    assert created.status_code == 201, created.text
    return int(created.json()["id"])


def _rejected(response: httpx.Response, field: str) -> None:
    assert response.status_code == 422, response.text
    assert any(field in str(item["loc"]) or field in item["msg"] for item in response.json()["detail"]), response.text


def test_counts_and_switches_must_have_their_json_type(
    client: TestClient, run_id: int, goal_set_with_photo: dict
) -> None:
    goal_set_id = goal_set_with_photo["id"]
    before = client.get(f"/api/runs/{run_id}").json()
    for episodes in (True, "5", 2.0):
        _rejected(client.post(f"/api/runs/{run_id}/robot/evaluate", json={"episodes": episodes}), "episodes")
    for body in ({"priority": True}, {"priority": "5"}, {"archived": 0}, {"archived": "false"}):
        _rejected(client.patch(f"/api/runs/{run_id}", json=body), next(iter(body)))
    run = {"env_id": "VisualPusher-v0", "goal_set_id": goal_set_id}
    for body in (
        {**run, "seed": "1"}, {**run, "priority": True}, {**run, "goal_set_id": str(goal_set_id)},
        {**run, "confirm_env_mismatch": 1}, {**run, "config": {"total_steps": True}},
        {**run, "config": {"query_budget": "5"}}, {**run, "config": {"remote_actor": 0}},
    ):  # fmt: skip
        field = next(name for name in ("seed", "priority", "confirm_env_mismatch", "total_steps", "query_budget",
                                       "remote_actor", "goal_set_id") if name in str(body))  # fmt: skip
        _rejected(client.post("/api/runs", json=body), field)
    sweep = {"env_id": "VisualPusher-v0", "goal_set_id": goal_set_id, "algorithms": ["vice_raq"]}
    _rejected(client.post("/api/runs/sweep", json={**sweep, "seeds": [True]}), "seeds")
    _rejected(client.post("/api/runs/sweep", json={**sweep, "seeds": ["0"]}), "seeds")
    _rejected(client.post("/api/goal-sets", json={"name": "g", "image_size": "48"}), "image_size")
    _rejected(client.post(f"/api/runs/{run_id}/continue", json={"total_steps": "900"}), "total_steps")
    _rejected(client.post("/api/queries/1/answer", json={"success": 1}), "success")
    # nothing stored changed
    assert [item["id"] for item in client.get("/api/runs", params={"all": "true"}).json()] == [run_id]
    after = client.get(f"/api/runs/{run_id}").json()
    assert (after["priority"], after["archived"]) == (before["priority"], before["archived"])
    assert [item["name"] for item in client.get("/api/goal-sets").json()] == [goal_set_with_photo["name"]]
    # the same values with their own types are taken
    assert client.patch(f"/api/runs/{run_id}", json={"priority": 5}).json()["priority"] == 5


def test_a_boolean_in_a_query_string_is_true_or_false(client: TestClient, run_id: int) -> None:
    for value in ("0", "1", "no", "off", "False"):
        _rejected(client.get("/api/runs", params={"archived": value}), "archived")
        _rejected(client.get("/api/runs", params={"all": value}), "all")
    assert [run["id"] for run in client.get("/api/runs", params={"archived": "false"}).json()] == [run_id]
    assert client.get("/api/runs", params={"archived": "true"}).json() == []


def test_an_id_in_a_path_is_digits_and_sweep_is_not_a_run(client: TestClient, run_id: int) -> None:
    for path in (f"/api/runs/%20{run_id}", f"/api/runs/{run_id}%20", f"/api/runs/+{run_id}", "/api/runs/1_0"):
        for method in ("GET", "PATCH", "DELETE"):
            response = client.request(method, path, json={"priority": 9} if method == "PATCH" else None)
            assert response.status_code in (404, 422), (method, path, response.status_code, response.text)
    for path in (f"/api/queries/%20{run_id}", f"/api/goal-sets/%20{run_id}", f"/api/runs/%20{run_id}/metrics"):
        assert client.get(path).status_code in (404, 422), path
    assert client.get(f"/api/runs/{run_id}").json()["priority"] == 0  # no PATCH reached the run
    for method in ("PATCH", "GET", "DELETE"):
        response = client.request(method, "/api/runs/sweep")
        assert response.status_code == 405, (method, response.text)
        assert response.headers["allow"] == "POST"


def test_405s_allow_every_method_the_spec_documents_for_the_path(client: TestClient, run_id: int) -> None:
    spec = client.get("/openapi.json").json()
    checked = 0
    for path, operations in spec["paths"].items():
        concrete = path.replace("{run_id}", str(run_id)).replace("{goal_set_id}", "1")
        concrete = concrete.replace("{example_id}", "1").replace("{query_id}", "1")
        response = client.options(concrete)
        assert response.status_code == 405, (path, response.status_code)
        allowed = {method.strip().lower() for method in response.headers["allow"].split(",")} - {"head"}
        assert allowed == set(operations), (path, response.headers["allow"], sorted(operations))
        checked += 1
    assert checked >= 30


def test_expensive_reads_are_refused_to_other_sites_pages(
    client: TestClient, run_id: int, goal_set_with_photo: dict, store: Store
) -> None:
    example_id = goal_set_with_photo["examples"][0]["id"] if "examples" in goal_set_with_photo else 1
    png = client.get(f"/api/goal-examples/{example_id}/image").content
    query = store.post_query(run_id=run_id, env_step=10, model_png=png, display_png=png, score=0.1)
    store.record_rollout(run_id=run_id, env_step=10, data=b"GIF89a", frame_count=1)
    reads = [
        "/api/envs/preview?env_id=VisualPusher-v0&size=48",
        "/api/envs/preview/image?env_id=VisualPusher-v0&size=48",
        f"/api/goal-examples/{example_id}/image",
        f"/api/queries/{query.id}/image",
        f"/api/runs/{run_id}/rollout/latest",
        f"/api/runs/{run_id}/metrics.csv",
        f"/api/runs/{run_id}/queries.zip",
        f"/api/runs/{run_id}/tensorboard.zip",
    ]
    for path in reads:
        refused = client.get(path, headers=CROSS_SITE)
        assert refused.status_code == 403, (path, refused.status_code)
        assert "another web site" in refused.json()["detail"]
        for headers in ({}, {"Sec-Fetch-Site": "same-origin"}, {"Sec-Fetch-Site": "none"}):
            assert client.get(path, headers=headers).status_code == 200, (path, headers)
    assert client.get("/api/runs", headers=CROSS_SITE).status_code == 200  # a cheap read is not refused


def test_a_preview_size_outside_the_list_is_a_clear_422(client: TestClient) -> None:
    for size in (47, 50, 500):
        response = client.get("/api/envs/preview", params={"env_id": "VisualPusher-v0", "size": size})
        assert response.status_code == 422, response.text
        assert "must be one of 16, 24, 32" in response.text
    assert client.get("/api/envs/preview", params={"env_id": "VisualPusher-v0", "size": 64}).status_code == 200


def test_80_concurrent_previews_keep_the_servers_memory_bounded(
    make_live_server: Callable[..., LiveServer],
) -> None:
    """Were: 80 callers at once, each a new size, took the server from about 235 to 830 MiB and it stayed there
    (every caller made its own env, each on a request thread that kept its rendering context)."""
    server = make_live_server()
    params = {"env_id": "VisualPusher-v0", "kind": "observation"}
    first = httpx.get(f"{server.url}/api/envs/preview/image", params={**params, "size": 48}, timeout=120)
    assert first.status_code == 200, first.text
    time.sleep(0.5)
    before = server.rss_bytes()

    def preview(size: int) -> int:
        got = httpx.get(f"{server.url}/api/envs/preview/image", params={**params, "size": size}, timeout=300)
        return got.status_code

    sizes = [size for size in range(16, 96)]
    with ThreadPoolExecutor(80) as pool:
        statuses = list(pool.map(preview, sizes))
    time.sleep(1)
    after = server.rss_bytes()
    print(f"80 concurrent previews: RSS {before / 2**20:.0f} -> {after / 2**20:.0f} MiB")
    assert {status for size, status in zip(sizes, statuses, strict=True) if size in PREVIEW_SIZES} == {200}
    assert {status for size, status in zip(sizes, statuses, strict=True) if size not in PREVIEW_SIZES} == {422}
    assert after - before < 80 * 2**20, (before, after)
