"""Everyday trips in Debian's Chromium against a real server and SQLite: a goal set's task and the confirm step
for a run of another, the Framing panel as the task is typed, how many goal photos to give, the answer queue's
order and goal photos, heartbeats of stopped runs, the runs table on a 390-px phone, one-point and negative
charts, and training a finished run further."""

import re
from pathlib import Path

import pytest
from playwright.sync_api import Page, expect
from test_browser import _scene, _shot
from test_browser_daily_use import watch

from contract.store import RunStatus, Store

pytestmark = pytest.mark.browser


def _photo(store: Store, goal_set_id: int, size: int, *, width: int | None = None) -> None:
    data = _scene(size, (74, 74))
    store.add_goal_example(
        goal_set_id=goal_set_id, filename=f"goal-{size}.png", original=data, original_media_type="image/png",
        width=width or size, height=size, model_png=_scene(48, (74, 74)), display_png=data,
    )  # fmt: skip


def _run(store: Store, name: str, **values: object) -> int:
    return store.create_run(
        env_id="VisualPusher-v0", algorithm="vice_raq", config={}, total_steps=25_000, name=name, **values
    ).id


def test_a_goal_set_for_a_task_its_photo_advice_framing_and_the_confirm_for_another_task(
    desktop: Page, live_server: str, store: Store, tmp_path: Path
) -> None:
    page = desktop
    problems = watch(page, live_server)
    page.goto(live_server + "/goal-sets")
    page.fill("#goal-set-name", "door open")
    page.fill("#goal-set-env", "VisualDoor-v0")
    page.click("#create-goal-set-button")
    page.wait_for_url(re.compile(r"/goal-sets/\d+$"))
    goal_set_id = int(page.url.rsplit("/", 1)[1])
    assert store.get_goal_set(goal_set_id=goal_set_id).env_id == "VisualDoor-v0"
    expect(page.locator("#goal-set-env")).to_have_text("photos of VisualDoor-v0")
    expect(page.locator("#goal-photo-advice")).to_contain_text("0 photos: too few")
    files = []
    for index in range(2):
        path = tmp_path / f"door-{index}.png"
        path.write_bytes(_scene(96, (30 + 20 * index, 74)))
        files.append(str(path))
    page.set_input_files("#goal-files", files)
    expect(page.locator(".example")).to_have_count(2)
    advice = page.locator("#goal-photo-advice")
    expect(advice).to_have_class(re.compile("warn"))
    expect(advice).to_contain_text("2 photos: too few. Give at least 10")
    expect(advice).to_contain_text("the paper used 80 on a real robot")

    # the Framing panel starts on the set's task and follows what is typed, without leaving the field
    expect(page.locator("#framing-env")).to_have_value("VisualDoor-v0")
    expect(page.locator("#framing-text")).not_to_have_text("Making the env…")
    with page.expect_response(lambda r: "/api/envs/preview" in r.url and "VisualPusher-v0" in r.url):
        page.locator("#framing-env").fill("VisualPusher-v0")
    expect(page.locator("#framing-env")).to_be_focused()
    _shot(page, "15-01-goal-set-task-advice-framing")

    # "Start a run with this set" opens the New run form on the set's task
    page.click("text=Start a run with this set")
    page.wait_for_url(re.compile(rf"/runs/new\?goal_set={goal_set_id}$"))
    expect(page.locator("#env_id")).to_have_value("VisualDoor-v0")
    page.fill("#total_steps", "5000")
    page.fill("#env_id", "VisualPusher-v0")
    asked: list[str] = []
    page.once("dialog", lambda dialog: (asked.append(dialog.message), dialog.dismiss()))
    page.click("#start-run")
    expect(page.locator('.field[data-field="goal_set_id"] .error')).to_contain_text(
        "made for VisualDoor-v0, not VisualPusher-v0"
    )
    assert asked and "Start it anyway?" in asked[0] and store.list_runs() == []
    _shot(page, "15-02-new-run-other-task")
    page.once("dialog", lambda dialog: dialog.accept())
    page.click("#start-run")
    page.wait_for_url(re.compile(r"/runs/\d+$"))
    [run] = store.list_runs()
    assert (run.env_id, run.goal_set_id) == ("VisualPusher-v0", goal_set_id)
    refused = [p for p in problems if p.startswith("409 ") and p.endswith("/api/runs")]
    assert len(refused) == 2 and [p for p in problems if p not in refused] == [], problems


def test_the_queue_shows_live_runs_first_and_each_goal_photo_once(
    desktop: Page, live_server: str, store: Store
) -> None:
    page = desktop
    problems = watch(page, live_server)
    goal_set = store.create_goal_set(name="pusher goals", env_id="VisualPusher-v0")
    _photo(store, goal_set.id, 48)  # a 48x48 render: the photo is the model's view
    _photo(store, goal_set.id, 96, width=128)  # a larger photo, cropped for the model: both are shown
    stopped, live = _run(store, "stopped", goal_set_id=goal_set.id), _run(store, "live", goal_set_id=goal_set.id)
    image = _scene(48, (70, 70))
    store.post_query(run_id=stopped, env_step=1000, model_png=image, display_png=image, score=1.0)
    store.request_stop(run_id=stopped)
    store.post_query(run_id=live, env_step=1000, model_png=image, display_png=image, score=1.0)
    page.goto(live_server + "/queue")
    expect(page.locator("#query-facts")).to_contain_text(f"#{live}")
    expect(page.locator("#nav-pending")).to_have_text("1")
    expect(page.locator("#pending-count")).to_have_text("2")
    expect(page.locator("#goal-strip figure")).to_have_count(3)
    expect(page.locator("#goal-strip figcaption").first).to_have_text("goal-48.png (the model's view)")
    _shot(page, "15-03-queue-live-first-photos-once")
    page.click("#answer-yes")
    expect(page.locator("#query-facts")).to_contain_text(f"#{stopped}")
    expect(page.locator("#nav-pending")).to_have_text("0")
    assert problems == [], problems


def test_the_runs_table_on_a_phone_and_no_heartbeat_age_for_stopped_runs(
    phone: Page, live_server: str, store: Store
) -> None:
    page = phone
    problems = watch(page, live_server)
    stopped = _run(store, "stopped one")
    store.claim_next_run(worker="learner-a")
    store.heartbeat(run_id=stopped, worker="learner-a", step=4000, status=RunStatus.TRAINING)
    store.request_stop(run_id=stopped)
    store.set_run_status(run_id=stopped, status=RunStatus.STOPPED, worker="learner-a")
    training = _run(store, "a run with a long name to see how it wraps on a phone")
    store.claim_next_run(worker="learner-a")
    store.heartbeat(run_id=training, worker="learner-a", step=6000, status=RunStatus.TRAINING, phase="training")
    page.goto(live_server + "/")
    row = page.locator(f'tr[data-run-id="{training}"]')
    expect(row.locator(".heartbeat-cell")).to_be_visible()
    expect(row.locator(".heartbeat-cell")).to_contain_text("ago")
    expect(page.locator(f'tr[data-run-id="{stopped}"] .heartbeat-cell')).to_have_text("–")
    pill = row.locator(".status").bounding_box()
    assert pill["height"] < 30 and pill["width"] > 50, pill  # "Training" on one line, not letter by letter
    for cell in ("Status", "Progress", "Success", "Queries", "Heartbeat"):
        box = row.locator(f'td[data-label="{cell}"]').bounding_box()
        assert box is not None and box["width"] >= 60 and box["x"] + box["width"] <= 390, (cell, box)
    assert page.evaluate("document.documentElement.scrollWidth") <= 390
    _shot(page, "15-04-phone-runs-table")
    page.goto(f"{live_server}/runs/{stopped}")
    expect(page.locator("#run-status")).to_contain_text("stopped")
    expect(page.locator("#stat-heartbeat")).to_have_text("–")
    assert problems == [], problems


def test_a_one_point_chart_negative_values_and_training_a_finished_run_further(
    desktop: Page, live_server: str, store: Store
) -> None:
    page = desktop
    problems = watch(page, live_server)
    run_id = _run(store, "finished")
    store.claim_next_run(worker="learner-a")
    store.heartbeat(run_id=run_id, worker="learner-a", step=25_000, status=RunStatus.TRAINING)
    store.record_metrics(run_id=run_id, step=1000, values={"eval/return": -389.246, "eval/success_rate": 0.25})
    store.set_run_status(run_id=run_id, status=RunStatus.FINISHED, worker="learner-a")
    page.goto(f"{live_server}/runs/{run_id}")
    chart = page.locator("#chart-return")
    expect(chart.locator("path.series")).to_have_count(1)
    labels = chart.locator("text.x-tick").all_text_contents()
    assert "1k" in labels and "999" not in labels and "1.001k" not in labels, labels
    assert labels == ["600", "800", "1k", "1.2k", "1.4k"], labels
    value = chart.locator('.chart-legend [data-series="eval/return"] b')
    expect(value).to_have_text("\u2212389.246")
    item = chart.locator('.chart-legend [data-series="eval/return"]')
    assert item.evaluate("e => e.getClientRects().length") == 1
    assert item.bounding_box()["height"] < 24  # label and value on one line
    y_labels = chart.locator("text.y-tick").all_text_contents()
    assert all(not label.startswith("-") for label in y_labels), y_labels
    _shot(page, "15-05-one-point-negative-chart")

    # a finished run: Continue to a new total, from its last checkpoint
    expect(page.locator("#resume-run")).to_be_hidden()
    expect(page.locator("#continue-steps")).to_have_value("50000")
    page.fill("#continue-steps", "40000")
    page.click("#continue-run")
    expect(page.locator("#run-status")).to_contain_text("queued")
    expect(page.locator("#continue-form")).to_be_hidden()
    run = store.get_run(run_id=run_id)
    assert (run.status, run.step, run.total_steps) == ("queued", 25_000, 40_000)
    expect(page.locator("#stat-step")).to_contain_text("25k / 40k")
    assert problems == [], problems
