"""Exports and the runs API additions, through the real app on a real SQLite file: metrics as CSV and as a
TensorBoard event file, queries with answers and images as a zip, the rollout as a video, priority / archive /
delete over HTTP, the env preview, and the server still without torch."""

import csv
import io
import subprocess
import sys
import zipfile
from pathlib import Path

from fastapi.testclient import TestClient
from PIL import Image

from app.exports import read_tensorboard_scalars
from contract.store import RunStatus, Store

ROOT = Path(__file__).resolve().parent.parent


def _png(color: tuple[int, int, int], size: int = 48) -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (size, size), color).save(buffer, format="PNG")
    return buffer.getvalue()


def _gif(frames: int = 5) -> bytes:
    images = [Image.new("RGB", (64, 64), (40 * i, 90, 160)) for i in range(frames)]
    buffer = io.BytesIO()
    images[0].save(buffer, format="GIF", save_all=True, append_images=images[1:], duration=100, loop=0)
    return buffer.getvalue()


def _trained_run(store: Store) -> int:
    run_id = store.create_run(env_id="VisualPusher-v0", algorithm="sparse", config={}, total_steps=2000).id
    store.claim_next_run(worker="w1")
    store.record_metrics(run_id=run_id, step=1000, values={"eval/return": -3.5, "eval/success_rate": 0.2})
    store.record_metrics(run_id=run_id, step=2000, values={"eval/return": -1.25})
    yes = store.post_query(run_id=run_id, env_step=1000, model_png=_png((255, 0, 0)), display_png=_png((255, 0, 0), 96),
                           score=2.5, ground_truth_success=1.0)  # fmt: skip
    store.post_query(run_id=run_id, env_step=2000, model_png=_png((0, 0, 255)), display_png=_png((0, 0, 255), 96),
                     score=0.5)  # fmt: skip
    store.answer_query(query_id=yes.id, success=True, labeler="ann")
    store.record_rollout(run_id=run_id, env_step=2000, data=_gif(), frame_count=5)
    store.set_run_status(run_id=run_id, status=RunStatus.FINISHED, worker="w1")
    return run_id


def test_metrics_as_csv_and_tensorboard(client: TestClient, store: Store) -> None:
    run_id = _trained_run(store)
    response = client.get(f"/api/runs/{run_id}/metrics.csv")
    assert response.status_code == 200 and response.headers["content-type"].startswith("text/csv")
    assert f"run-{run_id}-metrics.csv" in response.headers["content-disposition"]
    rows = list(csv.DictReader(io.StringIO(response.text)))
    assert [(r["step"], r["eval/return"], r["eval/success_rate"]) for r in rows] == [
        ("1000", "-3.5", "0.2"), ("2000", "-1.25", ""),
    ]  # fmt: skip
    archive = zipfile.ZipFile(io.BytesIO(client.get(f"/api/runs/{run_id}/tensorboard.zip").content))
    (name,) = archive.namelist()
    assert name.startswith(f"run-{run_id}/events.out.tfevents.")
    scalars = read_tensorboard_scalars(archive.read(name))  # every record's CRC32C checked
    assert sorted(scalars) == [(1000, "eval/return", -3.5), (1000, "eval/success_rate", 0.20000000298023224),
                               (2000, "eval/return", -1.25)]  # fmt: skip
    assert client.get("/api/runs/999/metrics.csv").status_code == 404


def test_queries_zip_rollout_video_and_policy_before_a_checkpoint(client: TestClient, store: Store) -> None:
    run_id = _trained_run(store)
    archive = zipfile.ZipFile(io.BytesIO(client.get(f"/api/runs/{run_id}/queries.zip").content))
    rows = list(csv.DictReader(io.StringIO(archive.read("queries.csv").decode())))
    assert [(r["env_step"], r["status"], r["answer"], r["labeler"], r["ground_truth_success"]) for r in rows] == [
        ("1000", "answered", "yes", "ann", "1.0"), ("2000", "pending", "", "", ""),
    ]  # fmt: skip
    image = Image.open(io.BytesIO(archive.read(rows[0]["model_image"])))
    assert image.size == (48, 48) and image.getpixel((3, 3)) == (255, 0, 0)
    assert Image.open(io.BytesIO(archive.read(rows[1]["display_image"]))).size == (96, 96)

    video = client.get(f"/api/runs/{run_id}/rollout.avi")
    assert video.status_code == 200 and video.headers["content-type"] == "video/x-msvideo"
    data = video.content
    assert data[:4] == b"RIFF" and data[8:12] == b"AVI " and int.from_bytes(data[4:8], "little") == len(data) - 8
    assert data.count(b"00dc") == 10  # 5 frames and their 5 index entries
    assert b"MJPG" in data[:400] and data.count(b"\xff\xd8\xff") == 5  # one JPEG per frame

    store.record_rollout(run_id=run_id, env_step=3000, data=b"GIF89a", frame_count=1)  # broken: 404, not 500
    broken = client.get(f"/api/runs/{run_id}/rollout.avi")
    assert broken.status_code == 404 and "not a readable GIF" in broken.json()["detail"]

    missing = client.get(f"/api/runs/{run_id}/policy")
    assert missing.status_code == 404 and "no checkpoint yet" in missing.json()["detail"]


def test_priority_archive_and_delete_over_http(client: TestClient, store: Store, tmp_path: Path) -> None:
    run_id = _trained_run(store)
    assert client.patch(f"/api/runs/{run_id}", json={"priority": 101}).status_code == 422
    changed = client.patch(f"/api/runs/{run_id}", json={"priority": 7, "archived": True}).json()
    assert (changed["priority"], changed["archived"]) == (7, True)
    assert [run["id"] for run in client.get("/api/runs").json()] == []
    assert [run["id"] for run in client.get("/api/runs?archived=true").json()] == [run_id]
    assert [run["id"] for run in client.get("/api/runs?all=true").json()] == [run_id]
    queued = client.post("/api/runs", json={"env_id": "VisualPusher-v0", "algorithm": "sparse", "priority": 3}).json()
    assert queued["priority"] == 3 and queued["waiting_reason"].startswith("waiting for a learner")
    assert client.patch(f"/api/runs/{queued['id']}", json={"archived": True}).status_code == 409
    checkpoint = tmp_path / "checkpoints" / f"run-{run_id}" / "checkpoint.pt"
    checkpoint.parent.mkdir(parents=True)
    checkpoint.write_bytes(b"x")
    assert client.delete(f"/api/runs/{run_id}").status_code == 204
    assert client.get(f"/api/runs/{run_id}").status_code == 404 and not checkpoint.parent.exists()
    assert client.get(f"/api/queries?run_id={run_id}").json() == []
    assert client.delete(f"/api/runs/{run_id}").status_code == 404
    store.claim_next_run(worker="w2")
    assert client.delete(f"/api/runs/{queued['id']}").status_code == 409  # a learner holds it


def test_env_preview_checks_the_id_first(client: TestClient) -> None:
    preview = client.get("/api/envs/preview", params={"env_id": "VisualPusher-v0"}).json()
    assert "reports success" in preview["description"]
    image = Image.open(io.BytesIO(client.get(preview["observation_url"]).content))
    assert image.size == (48, 48)
    refused = client.get("/api/envs/preview", params={"env_id": "os:system"})
    assert refused.status_code == 422 and "not one the operator allows" in refused.text
    assert "VisualDoor-v0" in client.get("/api/envs").json()["simulated"]


def test_envs_list_the_settings_each_simulated_task_learns_with(client: TestClient, goal_set_with_photo: dict) -> None:
    envs = client.get("/api/envs").json()
    assert set(envs["task_settings"]) == set(envs["simulated"])
    door = envs["task_settings"]["VisualDoor-v0"]
    assert door["fields"] == {"query_every": 1000, "query_budget": 50}
    assert door["results_page"] == "docs/results.md#door"
    for env_id, task in envs["task_settings"].items():  # each is a config a run can be created with
        body = {"env_id": env_id, "goal_set_id": goal_set_with_photo["id"], "config": task["fields"]}
        created = client.post("/api/runs", json=body)
        assert created.status_code == 201, created.text
        assert {name: created.json()["config"][name] for name in task["fields"]} == task["fields"]


def test_the_server_still_imports_no_torch() -> None:
    code = "import sys, app.main; print('torch' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False"


def test_a_sweep_starts_methods_times_seeds_and_compare_groups_them(
    client: TestClient, store: Store, goal_set_with_photo: dict
) -> None:
    body = {"env_id": "VisualPusher-v0", "algorithms": ["vice_raq", "vice"], "seeds": [0, 1, 2],
            "goal_set_id": goal_set_with_photo["id"], "name": "pusher", "config": {"total_steps": 5000}}  # fmt: skip
    runs = client.post("/api/runs/sweep", json=body).json()
    assert sorted((run["algorithm"], run["seed"]) for run in runs) == [
        (algorithm, seed) for algorithm in ("vice", "vice_raq") for seed in (0, 1, 2)
    ]
    assert runs[0]["name"] == "pusher · vice_raq · seed 0" and all(run["total_steps"] == 5000 for run in runs)
    # nothing is created when one combination is refused
    bad = client.post("/api/runs/sweep", json={**body, "algorithms": ["vice_raq", "vice_rag"]})
    assert bad.status_code == 422 and len(client.get("/api/runs").json()) == 6
    for index, run in enumerate(runs):
        for step in (1000, 2000):
            value = (0.2 if run["algorithm"] == "vice" else 0.5) + 0.1 * run["seed"] + step / 10_000
            store.record_metrics(run_id=run["id"], step=step, values={"eval/success_rate": value})
        if index == 0:
            store.record_metrics(run_id=run["id"], step=3000, values={"eval/success_rate": 1.0})  # only one seed
    ids = ",".join(str(run["id"]) for run in runs)
    groups = {group["label"]: group for group in client.get(f"/api/compare?runs={ids}").json()["groups"]}
    raq = groups["VisualPusher-v0 · vice_raq"]
    assert [point[0] for point in raq["points"]] == [1000, 2000]  # steps every seed reached
    step, mean, low, high, n = raq["points"][1]
    assert (step, round(mean, 6), round(low, 6), round(high, 6), n) == (2000, 0.8, 0.7, 0.9, 3)
    assert round(groups["VisualPusher-v0 · vice"]["points"][0][1], 6) == 0.4
    assert client.get(f"/api/compare?runs={ids}&metric=nope").status_code == 422
    assert client.get("/api/compare?runs=99999").status_code == 404
