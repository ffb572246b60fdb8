"""A robot at work in Debian's Chromium against a real server and SQLite. The actor is played by the test through
the store, as the learner's actor process calls it (report_actor with camera frames, request_scene_reset); the
person resets the scene and presses Ready (R, or the button), stops the robot (X, or the button) and resumes it,
on the answer queue and on the run page."""

import re

import pytest
from playwright.sync_api import Locator, Page, expect
from test_browser import _scene, _shot
from test_browser_daily_use import watch

from contract.store import RunStatus, Store

pytestmark = pytest.mark.browser


def _active_run(store: Store, name: str) -> int:
    """A run a learner holds (training), as the learner's claim and heartbeat make it."""
    run_id = store.create_run(env_id="VisualPusher-v0", algorithm="vice_raq", config={}, total_steps=5000, name=name).id
    assert store.claim_next_run(worker="robot-learner").id == run_id
    store.heartbeat(run_id=run_id, worker="robot-learner", step=100, status=RunStatus.TRAINING)
    return run_id


def _frame(puck: tuple[float, float]) -> bytes:
    return _scene(96, puck)


def _natural_width(image: Locator) -> int:
    return int(image.evaluate("image => image.naturalWidth"))


def test_the_queue_resets_the_scene_with_r_and_ready_and_stops_the_robot_with_x(
    desktop: Page, live_server: str, store: Store
) -> None:
    page = desktop
    problems = watch(page, live_server)
    run_id = _active_run(store, "arm on the table")
    store.report_actor(run_id=run_id, state="waiting for a scene reset", frame_png=_frame((30, 30)))
    store.request_scene_reset(run_id=run_id)
    page.goto(live_server + "/queue")

    card = page.locator(f'.robot-card[data-run-id="{run_id}"]')
    expect(card.locator(".robot-reset")).to_be_visible()
    expect(card.locator(".robot-reset")).to_have_text("Reset the scene, then press Ready R")
    expect(card).to_contain_text(f"run #{run_id} arm on the table")
    expect(card).to_contain_text("waiting for a scene reset")
    camera = card.locator("img.robot-camera")
    expect(camera).to_be_visible()
    expect(camera).to_have_attribute("src", re.compile(rf"^/api/runs/{run_id}/robot/camera\?v=\d+$"))
    assert _natural_width(camera) == 96
    first_src = camera.get_attribute("src")
    # the actor's next frame replaces the view by itself (polled about every 0.7 s)
    store.report_actor(run_id=run_id, state="waiting for a scene reset", frame_png=_frame((60, 60)))
    expect(camera).not_to_have_attribute("src", first_src or "")
    _shot(page, "robot-01-queue-reset-waiting")

    # R presses Ready
    page.keyboard.press("r")
    expect(card.locator(".robot-reset")).to_be_hidden()
    expect(card.locator(".robot-ready")).to_be_hidden()
    shown = page.request.get(f"{live_server}/api/runs/{run_id}/robot").json()
    assert (shown["reset_needed"], shown["reset_count"]) == (False, 1)
    expect(page.locator("#queue-message")).to_contain_text("Ready")

    # the next episode's reset, this time with the Ready button
    store.report_actor(run_id=run_id, state="episode over")
    store.request_scene_reset(run_id=run_id)
    expect(card.locator(".robot-reset")).to_be_visible()
    card.locator(".robot-ready").click()
    expect(card.locator(".robot-reset")).to_be_hidden()
    status = store.robot_status(run_id=run_id)
    assert (status.reset_needed, status.reset_count) == (False, 2)
    page.keyboard.press("r")  # no reset waits: nothing is sent, nothing counted
    expect(page.locator("#queue-message")).to_contain_text("No robot waits for a scene reset")
    assert store.robot_status(run_id=run_id).reset_count == 2

    # Stop robot (button), Resume, then X
    store.report_actor(run_id=run_id, state="moving")
    card.locator(".robot-stop").click()
    expect(card.locator(".robot-stopped")).to_be_visible()
    expect(card.locator(".robot-resume")).to_be_visible()
    expect(card.locator(".robot-stop")).to_be_hidden()
    assert store.robot_status(run_id=run_id).stop_requested is True
    # the actor's next report gets the stop in the same round trip
    assert store.report_actor(run_id=run_id, state="holding still").stop_requested is True
    _shot(page, "robot-02-queue-stopped")
    card.locator(".robot-resume").click()
    expect(card.locator(".robot-stop")).to_be_visible()
    expect(card.locator(".robot-stopped")).to_be_hidden()
    assert store.robot_status(run_id=run_id).stop_requested is False
    _stop_with_x_then_resume(page, card, store, run_id)

    # the run stops: its robot leaves the page
    store.set_run_status(run_id=run_id, status=RunStatus.STOPPED, worker="robot-learner")
    expect(page.locator("#robots")).to_be_hidden()
    assert problems == [], problems


def test_the_run_page_shows_the_robot_and_keys_wait_while_typing(desktop: Page, live_server: str, store: Store) -> None:
    page = desktop
    problems = watch(page, live_server)
    run_id = _active_run(store, "arm")
    store.report_actor(run_id=run_id, state="moving to the puck", frame_png=_frame((40, 70)))
    page.goto(f"{live_server}/runs/{run_id}")

    robots = page.locator("#robots")
    card = robots.locator(f'.robot-card[data-run-id="{run_id}"]')
    expect(card).to_contain_text("moving to the puck")
    camera = card.locator("img.robot-camera")
    expect(camera).to_be_visible()
    assert _natural_width(camera) == 96
    expect(card.locator(".robot-reset")).to_be_hidden()

    store.request_scene_reset(run_id=run_id)
    expect(card.locator(".robot-reset")).to_be_visible()
    expect(card.locator(".robot-ready")).to_be_visible()
    expect(card.locator(".robot-reset")).to_have_text("Reset the scene, then press Ready R")
    _shot(page, "robot-03-run-page-reset-waiting")
    # typing in a field: R and X do nothing
    page.locator("#run-priority").focus()
    page.keyboard.press("r")
    page.keyboard.press("x")
    page.wait_for_timeout(300)
    status = store.robot_status(run_id=run_id)
    assert (status.reset_needed, status.reset_count, status.stop_requested) == (True, 0, False)
    expect(card.locator(".robot-reset")).to_be_visible()
    page.locator("#run-priority").blur()
    page.keyboard.press("r")
    expect(card.locator(".robot-reset")).to_be_hidden()
    assert store.robot_status(run_id=run_id).reset_count == 1
    # the reset is counted in what the run cost the person
    expect(page.locator("#effort-text")).to_contain_text("0 answers (0.0 min answering) · 1 reset (the robot waited")
    expect(page.locator("#effort-text")).to_contain_text("person-minutes in all")

    _stop_with_x_then_resume(page, card, store, run_id)
    assert problems == [], problems

    # a run without an actor shows no robot
    other = store.create_run(env_id="VisualPusher-v0", algorithm="vice_raq", config={}, total_steps=5000).id
    page.goto(f"{live_server}/runs/{other}")
    expect(page.locator("#run-status")).to_contain_text("queued")
    page.wait_for_timeout(500)
    expect(page.locator("#robots")).to_be_hidden()


def _stop_with_x_then_resume(page: Page, card: Locator, store: Store, run_id: int) -> None:
    """X stops the robot (the store says so), Resume lets it act again."""
    page.keyboard.press("x")
    expect(card.locator(".robot-stopped")).to_be_visible()
    assert store.robot_status(run_id=run_id).stop_requested is True
    card.locator(".robot-resume").click()
    expect(card.locator(".robot-stop")).to_be_visible()
    expect(card.locator(".robot-stopped")).to_be_hidden()
    assert store.robot_status(run_id=run_id).stop_requested is False


def test_evaluate_now_on_the_run_page_and_its_questions_on_the_queue(
    desktop: Page, live_server: str, store: Store
) -> None:
    page = desktop
    problems = watch(page, live_server)
    run_id = _active_run(store, "arm")
    store.report_actor(run_id=run_id, state="acting", frame_png=_frame((40, 70)))
    page.goto(f"{live_server}/runs/{run_id}")

    card = page.locator(f'#robots .robot-card[data-run-id="{run_id}"]')
    episodes, evaluate = card.locator("input.robot-episodes"), card.locator("button.robot-evaluate")
    expect(evaluate).to_have_text("Evaluate now")
    expect(episodes).to_have_value("5")
    expect(card.locator(".robot-evaluating")).to_be_hidden()
    episodes.fill("3")
    page.keyboard.press("r")  # typing in the field: the robot's keys do nothing
    evaluate.click()
    expect(card.locator(".robot-evaluating")).to_have_text("Evaluating: 3 episodes left (round 1)")
    expect(evaluate).to_be_disabled()  # one round at a time
    status = store.robot_status(run_id=run_id)
    assert (status.evaluation_pending, status.evaluation_round, status.reset_count) == (3, 1, 0)
    _shot(page, "robot-04-run-page-evaluating")
    for left in (2, 1):  # the actor begins the episodes one by one
        assert store.take_evaluation_episode(run_id=run_id) == 1
        expect(card.locator(".robot-evaluating")).to_have_text(
            f"Evaluating: {left} episode{'s' if left > 1 else ''} left (round 1)"
        )
    store.take_evaluation_episode(run_id=run_id)
    expect(card.locator(".robot-evaluating")).to_be_hidden()
    expect(evaluate).to_be_enabled()

    # the last frame of an evaluation episode on the answer queue, with its tag; a training question has none
    store.post_query(
        run_id=run_id, env_step=180, model_png=_frame((50, 50)), display_png=_frame((50, 50)), score=0.3,
        strategy="evaluation", info={"evaluation_round": 1, "episode": 2},
    )  # fmt: skip
    store.post_query(run_id=run_id, env_step=200, model_png=_frame((20, 20)), display_png=_frame((20, 20)), score=1.0)
    page.goto(f"{live_server}/queue?run={run_id}")
    tag = page.locator("#query-tag")
    expect(tag).to_have_text("Last frame of evaluation episode 2 (round 1)")
    expect(page.locator("#query-facts")).to_contain_text("evaluation")
    expect(page.locator("#robots .robot-evaluate")).to_have_count(0)  # Evaluate now is the run page's
    _shot(page, "robot-05-queue-evaluation-question")
    page.keyboard.press("y")
    expect(tag).to_be_hidden()
    expect(page.locator("#query-facts")).to_contain_text("highest score since the last query")
    assert problems == [], problems
