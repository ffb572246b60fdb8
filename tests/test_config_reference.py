"""One definition of the run configuration: the form, the API, `raq config` and docs/configuration.md all show
TrainConfig's fields, by part, with their defaults and docstrings."""

import subprocess
import sys
from dataclasses import fields

import pytest
from conftest import ROOT
from fastapi.testclient import TestClient

import sim
from contract.config import CONFIG_PARTS, REAL_ROBOT_GOAL_IMAGES, TrainConfig, config_part, field_docs


def test_every_field_has_a_part_and_a_description() -> None:
    docs = field_docs()
    for field in fields(TrainConfig):
        assert docs.get(field.name), f"{field.name} has no docstring"
    assert config_part("device") == "execution" and config_part("updates_per_step") == "sac"
    assert config_part("env_id") == "task" and config_part("algorithm") == "method"
    execution = {field.name for field in fields(CONFIG_PARTS["execution"])}
    assert {"device", "precision", "num_envs", "replay_pipeline", "update_thread"} <= execution
    assert not execution & {field.name for field in fields(CONFIG_PARTS["classifier"])}


def test_the_docs_page_is_what_raq_config_prints() -> None:
    printed = subprocess.run([sys.executable, "-m", "cli", "config"], cwd=ROOT, capture_output=True, text=True)
    assert printed.returncode == 0, printed.stderr
    assert (ROOT / "docs" / "configuration.md").read_text() == printed.stdout, "run: raq config > docs/configuration.md"


def test_the_api_and_the_form_list_every_field(client: TestClient) -> None:
    parts = client.get("/api/config").json()
    listed = [entry["name"] for entries in parts.values() for entry in entries]
    assert sorted(listed) == sorted(field.name for field in fields(TrainConfig))
    batch = next(entry for entry in parts["sac"] if entry["name"] == "batch_size")
    assert batch["default"] == TrainConfig().batch_size and batch["description"] == "SAC minibatch size."
    page = client.get("/runs/new").text
    assert 'id="config-reference"' in page and "<code>watchdog_seconds</code>" in page


def test_the_real_robot_preset_is_the_papers_robot_settings() -> None:
    robot = TrainConfig.real_robot(seed=4)
    assert (robot.image_size, robot.conv_filters, robot.query_every, robot.eval_episodes) == (84, 32, 250, 0)
    assert robot.seed == 4 and robot.algorithm == "vice_raq" and REAL_ROBOT_GOAL_IMAGES == 80


def test_a_task_preset_sets_only_what_the_paper_set_per_task() -> None:
    """The queries' interval and budget and the episode length; every other field is one default for all tasks."""
    assert set(sim.PRESETS) == set(sim.TASKS.values())
    for env_id, preset in sim.PRESETS.items():
        assert set(preset) <= set(sim.PRESET_FIELDS), env_id
        TrainConfig(env_id=env_id, **preset)  # a valid run config


def test_the_paper_preset_is_the_published_algorithm_whatever_the_defaults() -> None:
    paper = TrainConfig.paper()
    assert (paper.classifier_steps, paper.classifier_lr, paper.no_answer_share) == (10, 1e-4, 0.0)
    assert (paper.encoder, paper.shared_encoder, paper.augmentation) == ("paper", False, "none")
    assert (paper.updates_per_step, paper.critic_layer_norm) == (1, False)
    assert paper.exploration_noise_beta == 0.0  # SAC's i.i.d. action noise
    assert TrainConfig().no_answer_share == 0.25


@pytest.mark.parametrize(
    ("name", "before", "now"), [("critic_layer_norm", False, True), ("exploration_noise_beta", 0.0, 1.0)]
)
def test_a_run_stored_before_a_field_resumes_as_it_ran(name: str, before: object, now: object) -> None:
    """A stored config without the field (runs from before it) keeps what they ran with (SAC's critics, i.i.d.
    action noise); new runs get the new default (LayerNorm critics, pink noise)."""
    stored = {field: value for field, value in TrainConfig().to_dict().items() if field != name}
    assert getattr(TrainConfig.from_dict(stored), name) == before
    assert getattr(TrainConfig(), name) == now
    assert getattr(TrainConfig.from_dict(TrainConfig().to_dict()), name) == now
