"""Daily use in Debian's Chromium against a real server and SQLite: why a queued run waits, priority, archive and
delete from the run page; /docs with every request outside the server refused; the runs, run and queue pages on a
390-px phone screen; no 404 (favicon) and no Content-Security-Policy violation anywhere."""

import re
from pathlib import Path

import pytest
from playwright.sync_api import Browser, Page, expect
from test_browser import _gif, _scene, _shot

from contract.store import RunStatus, Store

pytestmark = pytest.mark.browser


def watch(page: Page, server: str) -> list[str]:
    """Collect page errors, CSP violations and failed (4xx/5xx) responses of the page."""
    problems: list[str] = []
    page.on("pageerror", lambda error: problems.append(f"pageerror: {error}"))
    page.on("console", lambda m: problems.extend([m.text] if "Security Policy" in m.text else []))
    page.on("response", lambda r: problems.extend([f"{r.status} {r.url}"] if r.status >= 400 else []))
    return problems


def _run(store: Store, name: str, priority: int = 0) -> int:
    return store.create_run(
        env_id="VisualPusher-v0", algorithm="sparse", config={}, total_steps=25_000, name=name, priority=priority
    ).id


def test_why_a_run_waits_priority_archive_and_delete(desktop: Page, live_server: str, store: Store) -> None:
    page = desktop
    problems = watch(page, live_server)
    demo = _run(store, "demo", priority=-10)
    store.claim_next_run(worker="learner-a")
    store.heartbeat(run_id=demo, worker="learner-a", step=3000, status=RunStatus.TRAINING)
    mine, other = _run(store, "mine"), _run(store, "other")

    page.goto(live_server + "/")
    row = page.locator(f'tr[data-run-id="{mine}"]')
    expect(row.locator(".waiting-reason")).to_have_text(f"learner busy with #{demo}")
    expect(page.locator(f'tr[data-run-id="{other}"] .waiting-reason')).to_have_text(
        f"learner busy with #{demo}; after #{mine}"
    )
    expect(page.locator(f'tr[data-run-id="{demo}"]')).to_contain_text("p-10")
    _shot(page, "14-01-runs-why-waiting")

    # raise the other run's priority on its page: it moves ahead of mine
    page.goto(f"{live_server}/runs/{other}")
    expect(page.locator("#run-reason")).to_contain_text(f"learner busy with #{demo}")
    expect(page.locator("#archive-run")).to_be_hidden()  # queued: stop it before archiving
    page.fill("#run-priority", "5")
    page.locator("#run-priority").dispatch_event("change")
    expect(page.locator("#run-reason")).to_have_text(f"Queued: learner busy with #{demo}")
    assert store.get_run(run_id=other).priority == 5
    page.goto(live_server + "/")
    expect(page.locator(f'tr[data-run-id="{mine}"] .waiting-reason')).to_have_text(
        f"learner busy with #{demo}; after #{other}"
    )

    # stop, archive (gone from the runs, listed under Archived runs), then delete with everything
    page.goto(f"{live_server}/runs/{other}")
    page.click("#stop-run")
    expect(page.locator("#run-status")).to_contain_text("stopped")
    page.click("#archive-run")
    expect(page.locator("#archive-run")).to_have_text("Unarchive")
    page.goto(live_server + "/")
    expect(page.locator(f'tr[data-run-id="{mine}"]')).to_be_visible()
    expect(page.locator(f'tr[data-run-id="{other}"]')).to_have_count(0)
    page.click("#archive-toggle")
    expect(page.locator(f'tr[data-run-id="{other}"]')).to_be_visible()
    page.goto(f"{live_server}/runs/{other}")
    page.once("dialog", lambda dialog: dialog.accept())
    page.click("#delete-run")
    page.wait_for_url(live_server + "/")
    assert other not in [run.id for run in store.list_runs()]
    assert problems == [], problems


def test_api_docs_work_offline(desktop: Page, live_server: str) -> None:
    page = desktop
    problems = watch(page, live_server)
    outside: list[str] = []

    def only_this_server(route) -> None:  # type: ignore[no-untyped-def]
        if route.request.url.startswith(live_server):
            route.continue_()
        else:
            outside.append(route.request.url)
            route.abort()

    page.route("**/*", only_this_server)
    page.goto(live_server + "/docs")
    expect(page.locator(".swagger-ui .title").first).to_contain_text("vice-raq")
    expect(page.locator(".opblock-summary-path", has_text="/api/runs/{run_id}/metrics").first).to_be_visible()
    _shot(page, "14-02-docs-offline")
    assert outside == [] and problems == [], (outside, problems)


def test_phone_sized_runs_run_and_queue_pages(phone: Page, live_server: str, store: Store) -> None:
    page = phone
    problems = watch(page, live_server)
    run_id = _run(store, "a run with a long name to see how it wraps on a phone")
    store.claim_next_run(worker="learner-a")
    store.heartbeat(run_id=run_id, worker="learner-a", step=6000, status=RunStatus.TRAINING)
    for step in range(1000, 7000, 1000):
        store.record_metrics(run_id=run_id, step=step, values={"eval/success_rate": step / 10000, "eval/return": 1.0})
    store.record_rollout(run_id=run_id, env_step=6000, data=_gif(), frame_count=8)
    store.post_query(
        run_id=run_id, env_step=6000, model_png=_scene(48, (70, 70)), display_png=_scene(256, (70, 70)), score=2.0
    )

    def fits() -> None:
        width = page.evaluate("document.documentElement.scrollWidth")
        assert width <= 390, f"{page.url} is {width} px wide"
        assert page.locator(".topbar").bounding_box()["height"] <= 56  # the menu on one line

    page.goto(live_server + "/")
    expect(page.locator(f'tr[data-run-id="{run_id}"]')).to_be_visible()
    _shot(page, "14-03-phone-runs")
    fits()
    page.goto(f"{live_server}/runs/{run_id}")
    expect(page.locator("#stat-step")).to_contain_text("6k")
    fits()
    _shot(page, "14-04-phone-run")
    page.goto(live_server + "/queue")
    expect(page.locator("#answer-yes")).to_be_visible()
    fits()
    _shot(page, "14-05-phone-queue")
    page.locator("#answer-yes").tap()
    expect(page.locator("#queue-empty")).to_be_visible()
    assert re.search("answered yes", " ".join(e.message for e in store.events(run_id=run_id)))
    assert problems == [], problems


def test_own_env_preview_crop_note_framing_and_classifier_return(
    desktop: Page, live_server: str, store: Store, tmp_path
) -> None:  # type: ignore[no-untyped-def]
    page = desktop
    problems = watch(page, live_server)
    # a goal set with a landscape phone photo: the page says how it was cropped, and shows the run camera's framing
    page.goto(live_server + "/goal-sets")
    page.fill("#goal-set-name", "mug on coaster")
    page.click("#create-goal-set-button")
    page.wait_for_url(re.compile(r"/goal-sets/\d+$"))
    photo = tmp_path / "phone.jpg"
    from PIL import Image

    Image.open(__import__("io").BytesIO(_scene(600, (74, 74)))).resize((800, 600)).save(photo, format="JPEG")
    page.set_input_files("#goal-files", [str(photo)])
    expect(page.locator("#upload-status")).to_contain_text("the model sees the middle 600×600 of the 800×600 photo")
    expect(page.locator(".example .crop-note")).to_contain_text("75% of its width")
    expect(page.locator("#framing-text")).to_contain_text("reports success")
    expect(page.locator("#framing-observation")).to_have_js_property("naturalWidth", 48)
    expect(page.locator("#framing-display")).to_have_js_property("naturalWidth", 256)
    _shot(page, "14-06-goal-set-crop-and-framing")
    goal_set_id = int(page.url.rsplit("/", 1)[1])

    # the New run form: free text with suggestions, checked and previewed before the run starts
    page.goto(f"{live_server}/runs/new?goal_set={goal_set_id}")
    page.fill("#env_id", "VisualPusher-v1")
    expect(page.locator('.field[data-field="env_id"] .error')).to_contain_text("did you mean 'VisualPusher-v0'")
    page.fill("#env_id", "VisualDoor-v0")
    expect(page.locator("#env-preview-text")).to_contain_text("(3,)")
    expect(page.locator("#env-preview-observation")).to_have_js_property("naturalWidth", 48)
    _shot(page, "14-07-new-run-preview")
    # a simulated task fills in the settings it starts from; what was set by hand stays
    expect(page.locator("#query_every")).to_have_value("1000")
    expect(page.locator("#query_budget")).to_have_value("50")
    expect(page.locator("#task-settings-note")).to_contain_text("query_budget 50, query_every 1000")
    page.fill("#query_budget", "40")
    page.fill("#env_id", "VisualPusher-v0")
    expect(page.locator("#query_every")).to_have_value("5000")
    expect(page.locator("#task-settings-note")).to_contain_text("Kept what you set for query_budget")
    expect(page.locator("#query_budget")).to_have_value("40")
    assert page.input_value("#extra_config") == ""  # every other field is the one default of all tasks
    page.fill("#env_id", "VisualDoor-v0")
    expect(page.locator("#query_every")).to_have_value("1000")
    page.click("details:not(#sweep) summary")
    page.fill("#extra_config", '{"env_id": "VisualPicker-v0"}')  # typed here, it wins (it was silently replaced)
    asked: list[str] = []  # the goal set was made for the pusher (the form's first task): confirmed here
    page.once("dialog", lambda dialog: (asked.append(dialog.message), dialog.accept()))
    page.click("#start-run")
    page.wait_for_url(re.compile(r"/runs/\d+$"))
    run_id = int(page.url.rsplit("/", 1)[1])
    run = store.get_run(run_id=run_id)
    assert (run.env_id, run.config["query_every"], run.config["query_budget"]) == ("VisualPicker-v0", 1000, 40)
    assert asked and "made for VisualPusher-v0, not VisualPicker-v0" in asked[0], asked

    # an env without a reward: the classifier's return is drawn instead of a flat zero line; ticks never repeat
    store.claim_next_run(worker="learner-a")
    store.heartbeat(run_id=run_id, worker="learner-a", step=30_000, status=RunStatus.TRAINING)
    for step in range(10_000, 30_500, 500):
        store.record_metrics(
            run_id=run_id, step=step,
            values={"eval/return": 0.0, "eval/classifier_return": step / 1000 - 40, "eval/success_rate": 0.5},
        )  # fmt: skip
    query = store.post_query(run_id=run_id, env_step=30_000, model_png=_scene(48, (1, 1)), display_png=b"x", score=1.0)
    store.answer_query(query_id=query.id, success=False, labeler="ann")
    page.reload()
    expect(page.locator("#chart-classifier-return")).to_be_visible()
    expect(page.locator("#chart-classifier-return path.series")).to_have_count(1)
    expect(page.locator("#chart-return")).to_be_hidden()
    expect(page.locator("#events")).to_contain_text(f"query {query.id} answered no by ann")
    for chart in page.locator(".chart:visible").all():
        labels = chart.locator("text.x-tick").all_text_contents()
        assert len(labels) == len(set(labels)), labels
    _shot(page, "14-08-run-classifier-return")
    expected = [p for p in problems if p.startswith("422 ") and "env_id=VisualPusher-v1" in p]  # the misspelt id
    expected += [p for p in problems if p.startswith("409 ") and p.endswith("/api/runs")]  # before the confirm
    assert len(expected) == 2 and [p for p in problems if p not in expected] == [], problems


def test_exports_download_from_the_run_page(desktop: Page, live_server: str, store: Store) -> None:
    page = desktop
    problems = watch(page, live_server)
    run_id = _run(store, "export me")
    store.claim_next_run(worker="learner-a")
    store.record_metrics(run_id=run_id, step=1000, values={"eval/return": 2.0})
    query = store.post_query(run_id=run_id, env_step=1000, model_png=_scene(48, (1, 1)), display_png=b"x", score=1.0)
    store.answer_query(query_id=query.id, success=True)
    store.record_rollout(run_id=run_id, env_step=1000, data=_gif(), frame_count=8)
    page.goto(f"{live_server}/runs/{run_id}")
    expected = {
        "#export-metrics": f"run-{run_id}-metrics.csv", "#export-tensorboard": f"run-{run_id}-tb.zip",
        "#export-queries": f"run-{run_id}-queries.zip", "#export-video": f"run-{run_id}-step-1000.avi",
        "#export-gif": f"run-{run_id}-rollout.gif",
    }  # fmt: skip
    for selector, filename in expected.items():
        with page.expect_download() as download:
            page.click(selector)
        assert download.value.suggested_filename == filename
        assert Path(download.value.path()).stat().st_size > 0
    _shot(page, "14-09-run-exports")
    assert problems == [], problems


def test_honest_progress_and_a_notification_when_a_question_waits(
    browser: Browser,
    live_server: str,
    store: Store,
) -> None:
    context = browser.new_context(viewport={"width": 1360, "height": 900})
    context.grant_permissions(["notifications"], origin=live_server)
    # record what the page shows through the real Notification API
    context.add_init_script(
        "const Real = window.Notification; window.shown = [];"
        "window.Notification = class extends Real { constructor(title, options) { super(title, options);"
        " window.shown.push(title + ' | ' + (options && options.body)); } };"
    )
    page = context.new_page()
    page.set_default_timeout(15_000)
    problems = watch(page, live_server)
    run_id = store.create_run(
        env_id="VisualPusher-v0", algorithm="vice_raq", config={"query_every": 1000, "query_budget": 5},
        total_steps=20_000, goal_set_id=None,
    ).id  # fmt: skip
    store.claim_next_run(worker="learner-a")
    store.heartbeat(run_id=run_id, worker="learner-a", step=500, status=RunStatus.TRAINING, phase="warm-up")
    store.record_metrics(run_id=run_id, step=500, values={"perf/steps_per_second": 100.0})
    page.goto(f"{live_server}/runs/{run_id}")
    expect(page.locator("#run-phase")).to_have_text("warm-up")
    expect(page.locator("#stat-eta")).to_have_text("–")
    expect(page.locator("#stat-eta-sub")).to_contain_text("once training starts")
    expect(page.locator("#stat-next-query")).to_have_text("next question at step 1,000 (about 5 s)")
    store.heartbeat(run_id=run_id, worker="learner-a", step=2500, phase="evaluating")
    store.record_metrics(run_id=run_id, step=2500, values={"perf/steps_per_second": 10.0, "perf/eta_seconds": 1750.0})
    expect(page.locator("#run-phase")).to_have_text("evaluating")
    expect(page.locator("#stat-eta")).to_have_text("29 min 10 s")
    expect(page.locator("#stat-next-query")).to_have_text("next question at step 3,000 (about 50 s)")

    page.goto(f"{live_server}/queue")
    expect(page.locator("#notify-toggle")).to_have_text("Notifications on")  # permission granted to this origin
    expect(page.locator("#queue-empty")).to_be_visible()
    image = _scene(48, (1, 1))
    store.post_query(run_id=run_id, env_step=2500, model_png=image, display_png=image, score=1.0)
    expect(page.locator("#answer-yes")).to_be_visible()
    page.wait_for_function("window.shown.length === 1")
    assert page.evaluate("window.shown") == ["vice-raq: a question is waiting | 1 question waiting for your answer"]

    store.request_stop(run_id=run_id)
    store.set_run_status(run_id=run_id, status=RunStatus.STOPPED, worker="learner-a")
    page.goto(f"{live_server}/runs/{run_id}")
    expect(page.locator("#run-status")).to_contain_text("stopped")
    expect(page.locator("#stat-speed")).to_have_text("–")  # a stopped run shows no speed
    expect(page.locator("#run-phase")).to_have_text("waiting for answers (1)")
    _shot(page, "14-10-run-stopped-progress")
    assert problems == [], problems
    context.close()


def test_a_sweep_from_the_form_and_the_compare_page(desktop: Page, live_server: str, store: Store) -> None:
    page = desktop
    problems = watch(page, live_server)
    goal_set = store.create_goal_set(name="sweep goals")
    store.add_goal_example(
        goal_set_id=goal_set.id, filename="g.png", original=_scene(48, (74, 74)), original_media_type="image/png",
        width=48, height=48, model_png=_scene(48, (74, 74)), display_png=_scene(96, (74, 74)),
    )  # fmt: skip
    page.goto(f"{live_server}/runs/new?goal_set={goal_set.id}")
    page.fill("#total_steps", "5000")
    page.click("#sweep summary")
    page.check('input[name="sweep_algorithms"][value="vice_raq"]')
    page.check('input[name="sweep_algorithms"][value="vice"]')
    page.fill("#sweep_seeds", "0-2")
    page.click("#start-run")
    page.wait_for_url(re.compile(r"/compare\?runs="))
    runs = store.list_runs()
    expected = [(algorithm, seed) for algorithm in ("vice", "vice_raq") for seed in (0, 1, 2)]
    assert sorted((run.algorithm, run.seed) for run in runs) == expected
    for run in runs:
        for step in range(1000, 6000, 1000):
            value = min(1.0, step / 5000 * (0.6 if run.algorithm == "vice" else 1.0) + 0.05 * run.seed)
            store.record_metrics(run_id=run.id, step=step, values={"eval/success_rate": value, "eval/return": -step})
    page.reload()
    expect(page.locator("#compare-chart path.band")).to_have_count(2)
    expect(page.locator("#compare-chart path.series")).to_have_count(2)
    expect(page.locator("#compare-groups-body tr")).to_have_count(2)
    expect(page.locator('#compare-groups-body tr[data-group="VisualPusher-v0 · vice_raq"] td').nth(2)).to_have_text("1")
    _shot(page, "14-11-compare")
    page.select_option("#compare-metric", "eval/return")
    expect(page.locator("#compare-chart .chart-title")).to_have_text("Evaluation return")

    # the runs page: tick two runs, Compare selected
    page.goto(live_server + "/")
    page.check(f'input.compare-check[value="{runs[0].id}"]')
    page.check(f'input.compare-check[value="{runs[-1].id}"]')
    page.click("#compare-selected")
    page.wait_for_url(re.compile(r"/compare\?runs=\d+,\d+$"))
    expect(page.locator("#compare-groups-body tr")).to_have_count(2)
    assert problems == [], problems
