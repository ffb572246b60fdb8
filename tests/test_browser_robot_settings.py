"""The robot settings in Debian's Chromium against a real server (the stand-in robot, MuJoCo with MUJOCO_GL=egl)
and SQLite: choosing a robot env on the New run form fills in the robot preset the server gives for the learner's
device (TrainConfig.cpu_robot() on a CPU, the paper's real_robot() on a GPU) and the run starts with it; a run
page says when the learner cannot keep up with the robot, why, and the preset that fits."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import json
import re

import httpx
import pytest
from playwright.sync_api import Page, expect
from test_browser import _scene, _shot
from test_browser_daily_use import watch

from contract.config import TrainConfig, robot_preset_for
from contract.learner_pace import PACE_METRIC, SPEED_METRIC
from contract.store import RunStatus, Store

pytestmark = pytest.mark.browser
STANDIN = "robot.standin:PusherStandIn-v0"
FORM_INPUTS = ("query_every", "query_budget")  # robot preset fields with an input of their own on the form


def _with_photo(live_server: str, store: Store, name: str, image_size: int) -> int:
    goal_set = store.create_goal_set(name=name, env_id=STANDIN, image_size=image_size)
    files = {"files": ("goal.png", _scene(96, (40, 40)), "image/png")}
    reply = httpx.post(f"{live_server}/api/goal-sets/{goal_set.id}/examples", files=files, timeout=30)
    assert reply.status_code < 300, reply.text
    return goal_set.id


def _extra(page: Page) -> dict:
    text = page.input_value("#extra_config")
    return json.loads(text) if text else {}


def test_a_robot_env_gets_the_robot_settings_of_the_learners_device_in_one_choice(
    desktop: Page, live_server: str, store: Store
) -> None:
    page = desktop
    problems = watch(page, live_server)
    small = _with_photo(live_server, store, "arm at 48 px", 48)
    large = _with_photo(live_server, store, "arm at 84 px", 84)
    cpu, gpu = robot_preset_for("cpu"), robot_preset_for("cuda")

    # the set's robot env, a CPU learner (the form's default device): the CPU preset, every field of it
    page.goto(f"{live_server}/runs/new?goal_set={small}")
    expect(page.locator("#env_id")).to_have_value(STANDIN)
    note = page.locator("#task-settings-note")
    expect(note).to_contain_text(f"robot settings for a cpu learner of {STANDIN} at 5 Hz")
    expect(note).to_contain_text("TrainConfig.cpu_robot()")
    expect(page.locator("#query_every")).to_have_value(str(cpu.fields["query_every"]))
    expect(page.locator("#query_budget")).to_have_value(str(cpu.fields["query_budget"]))
    assert _extra(page) == {k: v for k, v in cpu.fields.items() if k not in FORM_INPUTS}
    assert (_extra(page)["image_size"], _extra(page)["conv_filters"]) == (48, 8)
    _shot(page, "robot-settings-01-cpu")

    # a GPU learner: the paper's 84 px and 32 filters; the 48 px goal set is named as the one to change
    page.select_option("#device", "cuda")
    expect(note).to_contain_text("TrainConfig.real_robot()")
    expect(note).to_contain_text("The goal set prepares its photos at 48 px: pick one of 84 px")
    assert _extra(page) == {k: v for k, v in gpu.fields.items() if k not in FORM_INPUTS}
    assert (_extra(page)["image_size"], _extra(page)["conv_filters"]) == (84, 32)
    page.select_option("#goal_set_id", str(large))
    expect(note).not_to_contain_text("pick one of")
    _shot(page, "robot-settings-02-gpu")

    # a simulated task puts its own settings back; the robot env again brings the robot preset
    page.fill("#env_id", "VisualDoor-v0")
    expect(page.locator("#query_every")).to_have_value("1000")
    assert page.input_value("#extra_config") == ""
    page.fill("#env_id", STANDIN)
    expect(note).to_contain_text("TrainConfig.real_robot()")
    expect(page.locator("#query_every")).to_have_value(str(gpu.fields["query_every"]))

    page.click("#start-run")
    page.wait_for_url(re.compile(r"/runs/\d+$"))
    run = store.get_run(run_id=int(page.url.rsplit("/", 1)[1]))
    assert run.env_id == STANDIN and run.config["device"] == "cuda"
    assert {name: run.config[name] for name in gpu.fields} == gpu.fields
    assert problems == [], problems


def test_the_robot_settings_api_answers_by_env_and_device(live_server: str) -> None:
    def ask(**params: str) -> httpx.Response:
        return httpx.get(f"{live_server}/api/envs/robot-settings", params=params, timeout=60)

    cpu = ask(env_id=STANDIN).json()
    assert (cpu["control_hz"], cpu["device"], cpu["preset"]) == (5.0, "cpu", "cpu_robot")
    assert cpu["fields"] == robot_preset_for("cpu").fields
    gpu = ask(env_id=STANDIN, device="cuda:1").json()
    assert (gpu["preset"], gpu["fields"]["image_size"], gpu["fields"]["conv_filters"]) == ("real_robot", 84, 32)
    lockstep = ask(env_id="VisualPusher-v0", device="cuda").json()
    assert (lockstep["control_hz"], lockstep["preset"], lockstep["fields"]) == (0.0, None, {})
    assert ask(env_id=STANDIN, device="tpu").status_code == 422
    refused = ask(env_id="os:Anything-v0")
    assert refused.status_code == 422 and "RAQ_ENV_MODULES" in refused.text


def test_the_run_page_says_the_learner_cannot_keep_up_and_what_fits(
    desktop: Page, live_server: str, store: Store
) -> None:
    page = desktop
    problems = watch(page, live_server)
    config = TrainConfig.real_robot(env_id=STANDIN).to_dict()
    run_id = store.create_run(env_id=STANDIN, algorithm="vice_raq", config=config, total_steps=15_000).id
    store.claim_next_run(worker="robot-learner")
    store.heartbeat(run_id=run_id, worker="robot-learner", step=1500, status=RunStatus.TRAINING)
    store.record_metrics(run_id=run_id, step=1000, values={SPEED_METRIC: 5.0})  # the robot at 5 Hz: 50 s a record
    store.record_metrics(run_id=run_id, step=1250, values={SPEED_METRIC: 5.0, PACE_METRIC: 1.9})

    page.goto(f"{live_server}/runs/{run_id}")
    expect(page.locator("#person-effort")).to_be_visible()
    expect(page.locator("#learner-pace")).to_be_hidden()  # keeping up: nothing said

    store.record_metrics(run_id=run_id, step=1500, values={SPEED_METRIC: 5.0, PACE_METRIC: 0.6})
    store.record_metrics(run_id=run_id, step=1750, values={SPEED_METRIC: 5.0, PACE_METRIC: 0.6})
    page.reload()
    pace = page.locator("#learner-pace")
    expect(pace).to_be_visible()
    expect(pace).to_contain_text("cannot keep up with the robot")
    expect(pace).to_contain_text("84 px and 32 filters on this CPU give 0.6 updates a robot step")
    expect(pace).to_contain_text("TrainConfig.cpu_robot(): image_size 48, conv_filters 8")
    _shot(page, "robot-settings-03-learner-behind")
    assert problems == [], problems
