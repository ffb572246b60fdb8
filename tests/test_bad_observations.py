"""Observations are checked: an env whose observations are not images the networks can take (NaN values, floats
outside [0, 1], a string, a grey H x W array) is refused when the run is created, in the New run form's preview and
in the API, and a run of one that goes bad later fails on the learner at once, its reason naming the env and the
problem (no training on black frames, no silent clipping, no numpy error)."""

from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from test_learner_run import create_run, tiny_config

from app.migrate import upgrade
from contract.envs import observation_problem
from contract.settings import Settings
from contract.store import RunStatus, Store
from learner.worker import work

PROBLEMS = {
    "learner.testing_envs:VisualNaN-v0": "observation has NaN values",
    "learner.testing_envs:VisualHuge-v0": "observation is float with values from 0 to 1e+09",
    "learner.testing_envs:VisualText-v0": "observation is str, not an image",
    "learner.testing_envs:VisualGray-v0": "observation has shape (24, 24), not an RGB image",
}


def test_the_one_check_accepts_images_and_names_what_is_wrong_with_the_rest() -> None:
    image = np.zeros((8, 8, 3), dtype=np.uint8)
    assert observation_problem(image) is None
    assert observation_problem(np.ones((3, 8, 8), dtype=np.float32)) is None  # CHW, float in [0, 1]
    assert observation_problem({"pixels": image}) is None
    inf = np.zeros((8, 8, 3), dtype=np.float64)
    inf[1, 1, 1] = np.inf
    assert observation_problem(inf) == "observation has infinite values"
    assert "float with values from -0.5" in (observation_problem(np.full((8, 8, 3), -0.5)) or "")
    assert "dtype int64" in (observation_problem(np.zeros((8, 8, 3), dtype=np.int64)) or "")
    assert "shape (4,)" in (observation_problem(np.zeros(4)) or "")
    assert "without an 'image'" in (observation_problem({"state": image}) or "")


@pytest.mark.parametrize("env_id", sorted(PROBLEMS))
def test_a_run_of_an_env_with_bad_observations_is_refused_in_the_preview_and_the_api(
    client: TestClient, env_id: str
) -> None:
    expected = f"{env_id}: {PROBLEMS[env_id]}"
    preview = client.get("/api/envs/preview", params={"env_id": env_id})
    assert preview.status_code == 422, preview.text
    assert preview.json()["detail"][0]["msg"].startswith(expected)
    created = client.post("/api/runs", json={"env_id": env_id, "algorithm": "sparse"})
    assert created.status_code == 422, created.text
    (error,) = created.json()["detail"]
    assert error["loc"] == ["body", "env_id"] and error["msg"].startswith(f"env_id: {expected}")
    assert client.get("/api/runs").json() == []  # nothing stored
    # the good env of the same module is still fine
    good = client.post("/api/runs", json={"env_id": "learner.testing_envs:DotReach-v0", "algorithm": "sparse"})
    assert good.status_code == 201, good.text


@pytest.mark.parametrize(
    ("env_id", "problem"),
    [
        ("learner.testing_envs:VisualNaNLater-v0", "observation has NaN values"),  # good at reset, NaN from step 3
        ("learner.testing_envs:VisualHuge-v0", "observation is float with values from 0 to 1e+09"),
    ],
)
def test_the_learner_fails_a_run_whose_observations_go_bad_at_once_saying_why(
    tmp_path: Path, env_id: str, problem: str
) -> None:
    url = f"sqlite:///{tmp_path / 'raq.sqlite3'}"
    upgrade(url)
    store = Store(url)
    try:
        settings = Settings(_env_file=None, data_dir=tmp_path, database_url=url)
        run_id = create_run(store, None, tiny_config(env_id=env_id, algorithm="sparse"))
        assert work(settings, worker_name="checker", once=True) == 1
        run = store.get_run(run_id=run_id)
        assert run.status == RunStatus.FAILED
        assert run.status_reason.startswith(f"{env_id}: {problem}"), run.status_reason
        assert (run.step or 0) <= 3  # it failed on the first bad observation, before any training
    finally:
        store.dispose()
