"""Taking over a robot from the run page in Debian's Chromium, with real processes: the robot's own process
(`raq robot`), a learner, `raq serve` and the person's keyboard. Holding a key drives the stand-in robot by hand
and the learner keeps those steps; on the recording arm, a held key cannot send actions faster than the robot's
pace, and a Stop pressed while the key is still held ends the take-over: nothing moves until Resume."""

import time
from pathlib import Path

import numpy as np
import pytest
from conftest import STANDIN, create_run, robot_subprocess, run_live_server
from playwright.sync_api import Page, expect
from recording_arm import ENV_ID, recorded_by
from test_actor import arm_env, real_time_config
from test_browser_robot import _frame
from test_stop_means_stop import a_run, arm, calls_after, learner_process, wait_until  # noqa: F401 - a fixture

from contract.settings import Settings
from contract.store import Store

pytestmark = pytest.mark.browser

ARM_HZ = 10.0


def _sent(log: Path, after: float) -> list[tuple[float, float, int]]:
    """(when, first number, process) of each action the recording arm sent after `after`."""
    entries = recorded_by(log)
    return [
        (at, value, pid)
        for (what, at, pid), (then, value, _) in zip(entries, entries[1:], strict=False)
        if what == "action" and then == "sent" and at > after
    ]


def _open_run_page(page: Page, url: str, run_id: int) -> None:
    page.goto(f"{url}/runs/{run_id}")
    expect(page.locator("#takeover-keys")).to_contain_text("← → or A D (x)", timeout=120_000)
    expect(page.locator("#takeover-driver")).to_have_text("The policy drives.")


def test_the_keyboard_drives_the_stand_in_robot_and_the_learner_keeps_those_steps(
    desktop: Page, store: Store, tmp_path: Path
) -> None:
    page = desktop
    settings = Settings(_env_file=None, database_url=store.url, data_dir=tmp_path)
    config = real_time_config(
        env_id=STANDIN, algorithm="sparse", control_hz=5.0, reset_every_episode=False, total_steps=100_000,
        episode_steps=100, initial_random_steps=20, image_size=16, log_every=10,
    )  # fmt: skip
    run_id = create_run(store, None, config)
    env = {**arm_env(settings, tmp_path / "unused.log"), "RAQ_ENV_MODULES": "learner.testing_envs,robot.standin"}
    with (
        robot_subprocess(env, STANDIN, store, tmp_path / "robot.log"),
        learner_process(env, tmp_path / "learner.log"),
        run_live_server(store.url, tmp_path, {"RAQ_ENV_MODULES": "learner.testing_envs,robot.standin"}) as server,
    ):
        _open_run_page(page, server.url, run_id)
        expect(page.locator("#takeover-keys")).to_contain_text("↓ ↑ or S W (y)")
        expect(page.locator("#takeover-keys")).not_to_contain_text("Q E")  # the pusher moves in x and y only
        card = page.locator(f'.robot-card[data-run-id="{run_id}"]')
        expect(card.locator(".robot-ready")).to_be_visible(timeout=60_000)  # the stand-in asks for a scene reset
        page.keyboard.press("r")
        expect(card.locator(".robot-state")).to_contain_text("Actor: acting", timeout=30_000)
        page.keyboard.down("ArrowRight")
        page.keyboard.down("w")
        expect(page.locator("#takeover-driver")).to_have_text("You drive.")
        expect(card.locator(".robot-state")).to_contain_text("driven by hand", timeout=10_000)
        time.sleep(3.0)
        page.keyboard.up("w")
        page.keyboard.up("ArrowRight")
        expect(page.locator("#takeover-driver")).to_have_text("The policy drives.")
        expect(card.locator(".robot-state")).to_contain_text("Actor: acting", timeout=10_000)
        wait_until(
            lambda: any(m.value >= 10 for m in store.metrics(run_id=run_id, names=["person/steps"])),
            60, "the learner to keep the steps driven by hand (5 Hz for 3 s)",
        )  # fmt: skip
        effort = page.request.get(f"{server.url}/api/runs/{run_id}").json()["effort"]
        assert effort["takeovers"] == 1 and 2.5 <= effort["takeover_seconds"] <= 5.0, effort
        expect(page.locator("#effort-text")).to_contain_text("1 take-over")


def test_a_held_key_cannot_outrun_the_robots_pace_or_a_stop(
    desktop: Page,
    arm: tuple[Settings, Store, Path],  # noqa: F811 - the fixture
    tmp_path: Path,
) -> None:
    page = desktop
    settings, store, log = arm
    run_id = a_run(store, initial_random_steps=50, control_hz=ARM_HZ)
    env = arm_env(settings, log)
    period = 1.0 / ARM_HZ
    modules = {"RAQ_ENV_MODULES": "learner.testing_envs,recording_arm", "PYTHONPATH": env["PYTHONPATH"]}
    with (
        robot_subprocess(env, ENV_ID, store, tmp_path / "robot.log") as robot,
        learner_process(env, tmp_path / "learner.log"),
        run_live_server(store.url, tmp_path, modules) as server,
    ):
        _open_run_page(page, server.url, run_id)
        began = time.monotonic()
        page.keyboard.down("d")
        expect(page.locator("#takeover-driver")).to_have_text("You drive.")
        time.sleep(3.0)
        held = [entry for entry in _sent(log, began)]
        mine = [at for at, value, _ in held if value == pytest.approx(1.0)]
        assert len(mine) >= 15  # the person's (+1 in x) for most of 3 s (a busy page posting late: a policy step)
        assert {pid for _, _, pid in held} == {robot.pid}
        assert min(np.diff([at for at, _, _ in held])) >= 0.9 * period  # (the page sends twice a period)

        page.keyboard.press("x")  # Stop robot, the drive key still held
        stopped = time.monotonic()
        expect(page.locator("#takeover-driver")).to_have_text("Stopped: nobody drives until Resume.")
        time.sleep(2.5)
        assert calls_after(log, stopped + period + 0.1, ("action", "reset")) == []
        assert store.robot_status(run_id=run_id).takeover_action is None
        page.keyboard.up("d")
        page.locator(f'.robot-card[data-run-id="{run_id}"] .robot-resume').click()
        resumed = time.monotonic()
        wait_until(lambda: len(_sent(log, resumed)) >= 5, 30, "the arm to move after Resume")
        assert all(value != pytest.approx(1.0) for _, value, _ in _sent(log, resumed)[:5])  # the policy's


def test_the_success_key_record_demos_and_a_call_for_help_on_the_run_page(
    desktop: Page, live_server: str, store: Store
) -> None:
    """The actor is played through the store here, as the robot's process calls it: G marks a success, Record demos
    asks for episodes by hand, and a run whose recent questions were all "no" asks for help on its page and on the
    queue's robot card."""
    from test_takeover import announced  # noqa: PLC0415

    page = desktop
    run = store.create_run(env_id=ENV_ID, algorithm="vice_raq", config={}, total_steps=5000, name="arm")
    assert store.claim_next_run(worker="robot-learner").id == run.id
    store.heartbeat(run_id=run.id, worker="robot-learner", step=3000, status="training")
    store.report_actor(run_id=run.id, state="acting")
    announced(store, run.id)
    page.goto(f"{live_server}/runs/{run.id}")
    expect(page.locator("#takeover-keys")).to_contain_text("G: the episode is a success")
    expect(page.locator("#takeover-help")).to_have_text("")
    page.keyboard.press("g")
    expect(page.locator(".toast").last).to_contain_text("Marked a success")
    assert store.robot_status(run_id=run.id).success_marks == 1
    page.locator("#demo-episodes").fill("2")
    page.locator("#record-demos").click()
    expect(page.locator("#takeover-demos")).to_contain_text("2 more to begin")
    expect(page.locator("#record-demos")).to_be_disabled()
    assert store.robot_status(run_id=run.id).demo_pending == 2

    for number in range(10):  # ten questions after the warm-up, every answer no
        query = store.post_query(
            run_id=run.id, env_step=1500 + 100 * number, model_png=_frame((20, 20)), display_png=_frame((20, 20)),
            score=-2.0,
        )  # fmt: skip
        store.answer_query(query_id=query.id, success=False)
        store.report_actor(run_id=run.id, state="acting")
    expect(page.locator("#takeover-help")).to_contain_text("The run asks for help", timeout=10_000)
    page.goto(f"{live_server}/queue")
    expect(page.locator(f'.robot-card[data-run-id="{run.id}"] .robot-help')).to_be_visible()
