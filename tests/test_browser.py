"""The pages in Debian's Chromium (Playwright for Python) against a real server and a real SQLite file.

No learner runs here: the test writes a query, metrics, a heartbeat and a rollout through the Store,
exactly as the learner would, and checks what a person sees and does.
"""

import io
import re
from collections.abc import Callable
from pathlib import Path

import pytest
from conftest import LiveServer
from PIL import Image, ImageDraw
from playwright.sync_api import Page, expect

from contract.store import RunStatus, Store

ARTIFACTS = Path(__file__).resolve().parent.parent / "test-artifacts"
pytestmark = pytest.mark.browser


def _scene(size: int, puck_at: tuple[float, float], *, fmt: str = "PNG") -> bytes:
    """A pusher-like picture: table, red target, blue puck."""
    image = Image.new("RGB", (size, size), (214, 196, 160))
    draw = ImageDraw.Draw(image)
    s = size / 100
    draw.ellipse((62 * s, 62 * s, 86 * s, 86 * s), fill=(200, 40, 40))
    x, y = puck_at
    draw.ellipse(((x - 8) * s, (y - 8) * s, (x + 8) * s, (y + 8) * s), fill=(40, 70, 200))
    draw.rectangle((10 * s, 40 * s, 30 * s, 46 * s), fill=(90, 90, 90))
    buffer = io.BytesIO()
    image.save(buffer, format=fmt)
    return buffer.getvalue()


def _gif() -> bytes:
    frames = [Image.open(io.BytesIO(_scene(128, (20 + 8 * i, 20 + 8 * i)))).convert("P") for i in range(8)]
    buffer = io.BytesIO()
    frames[0].save(buffer, format="GIF", save_all=True, append_images=frames[1:], duration=120, loop=0)
    return buffer.getvalue()


def _shot(page: Page, name: str) -> None:
    ARTIFACTS.mkdir(exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / f"{name}.png"), full_page=True)


def test_goal_photos_run_queue_and_curves(page: Page, live_server: str, store: Store, tmp_path: Path) -> None:
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    # every response carries a Content-Security-Policy: anything it blocks shows up as a console error
    page.on("console", lambda message: errors.extend([message.text] if "Security Policy" in message.text else []))

    # 1. a goal set with two photos uploaded through the page
    page.goto(f"{live_server}/goal-sets")
    expect(page.get_by_text("No goal sets yet")).to_be_visible()
    page.fill("#goal-set-name", "puck on the red target")
    page.click("#create-goal-set-button")
    page.wait_for_url(re.compile(r"/goal-sets/\d+$"))
    photos = []
    for index, puck in enumerate([(74, 74), (72, 76)]):
        path = tmp_path / f"goal-{index}.{'png' if index == 0 else 'jpg'}"
        path.write_bytes(_scene(400, puck, fmt="PNG" if index == 0 else "JPEG"))
        photos.append(str(path))
    page.set_input_files("#goal-files", photos)
    expect(page.locator(".example")).to_have_count(2)
    expect(page.locator(".example img.pixelated").first).to_have_js_property("naturalWidth", 48)
    _shot(page, "01-goal-set")
    goal_set_id = int(page.url.rsplit("/", 1)[1])
    assert len(store.list_goal_examples(goal_set_id=goal_set_id)) == 2

    # a broken file is refused with a message, nothing stored
    broken = tmp_path / "broken.png"
    broken.write_bytes(b"not really a png")
    page.set_input_files("#goal-files", [str(broken)])
    expect(page.locator("#upload-status")).to_contain_text("broken.png")
    assert len(store.list_goal_examples(goal_set_id=goal_set_id)) == 2

    # 2. a run started from the new-run page; a bad value first shows the error beside its field
    page.goto(f"{live_server}/runs/new")
    page.fill("#env_id", "VisualPusher-v0")
    expect(page.locator("#env-preview-text")).to_contain_text("reports success")
    expect(page.locator("#goal_set_id")).to_have_value(str(goal_set_id))
    page.fill("#query_every", "0")
    page.click("#start-run")
    expect(page.locator('.field[data-field="query_every"] .error')).to_contain_text("at least 1")
    _shot(page, "02-new-run-error")
    page.fill("#query_every", "500")
    page.fill("#total_steps", "20000")
    page.click("#start-run")
    page.wait_for_url(re.compile(r"/runs/\d+$"))
    run_id = int(page.url.rsplit("/", 1)[1])
    run = store.get_run(run_id=run_id)
    assert (run.status, run.goal_set_id, run.config["query_every"], run.total_steps) == (
        "queued",
        goal_set_id,
        500,
        20000,
    )
    expect(page.locator("#run-status")).to_contain_text("queued")

    # 3. the learner's writes, made here through the store
    claimed = store.claim_next_run(worker="test-learner")
    assert claimed is not None and claimed.id == run_id
    store.heartbeat(run_id=run_id, worker="test-learner", step=6000, status=RunStatus.TRAINING)
    for step in range(1000, 7000, 1000):
        progress = step / 6000
        store.record_metrics(
            run_id=run_id,
            step=step,
            values={
                "eval/success_rate": round(0.75 * progress, 3),
                "eval/return": -40 + 30 * progress,
                "train/episode_return": -45 + 28 * progress,
                "reward/loss": 0.7 * (1 - 0.6 * progress),
                "reward/acc_goal": 0.6 + 0.35 * progress,
                "reward/acc_replay": 0.55 + 0.4 * progress,
                "reward/mean_logit_goal": 3 * progress,
                "reward/mean_logit_recent": -2 + progress,
                "queries/asked": step // 2000,
                "queries/answered": max(0, step // 2000 - 1),
                "queries/yes": max(0, step // 3000 - 1),
                "critic/loss": 1.2 - progress,
                "actor/loss": -2 * progress,
                "alpha/value": 1.0 - 0.8 * progress,
                "perf/steps_per_second": 85.0,
                "perf/eta_seconds": 14000 / 85.0,
            },
        )
    store.record_rollout(run_id=run_id, env_step=6000, data=_gif(), frame_count=8, success=1.0, episode_return=-12.5)
    query = store.post_query(
        run_id=run_id, env_step=5500, model_png=_scene(48, (70, 72)), display_png=_scene(256, (70, 72)), score=2.2,
        ground_truth_success=1.0, info={"puck_to_goal": 0.03},
    )  # fmt: skip

    # 4. answer it with the keyboard in the queue
    page.goto(f"{live_server}/queue?run={run_id}")
    expect(page.locator("#queue-item")).to_be_visible()
    expect(page.locator("#query-facts")).to_contain_text("2.2")
    expect(page.locator("#goal-strip img")).to_have_count(4)  # two photos, each as taken and as the model sees it
    expect(page.locator("#query-display")).to_have_js_property("naturalWidth", 256)
    _shot(page, "03-queue")
    page.keyboard.press("y")
    expect(page.locator("#queue-empty")).to_be_visible()
    expect(page.get_by_text("No queries waiting.")).to_be_visible()
    expect(page.locator("#nav-pending")).to_have_text("0")
    answered = store.get_query(query_id=query.id)
    assert (answered.status, answered.answer, answered.labeler) == ("answered", True, "web")
    _shot(page, "04-queue-empty")

    # U undoes while the learner has not read the answer; once it has, the 409 message shows
    page.keyboard.press("u")
    expect(page.locator("#queue-item")).to_be_visible()
    assert store.get_query(query_id=query.id).status == "pending"
    page.keyboard.press("n")
    expect(page.locator("#queue-empty")).to_be_visible()
    assert store.get_query(query_id=query.id).answer is False
    store.new_answers(run_id=run_id)  # the learner takes the answer into its classifier
    page.keyboard.press("u")
    expect(page.locator("#queue-message")).to_contain_text("already used")
    assert store.get_query(query_id=query.id).answer is False

    # a new query arrives without a reload
    store.post_query(run_id=run_id, env_step=6500, model_png=_scene(48, (30, 30)), display_png=_scene(256, (30, 30)),
                     score=0.4, ground_truth_success=0.0)  # fmt: skip
    expect(page.locator("#queue-item")).to_be_visible(timeout=10_000)
    page.keyboard.press("s")
    expect(page.locator("#queue-empty")).to_be_visible()

    # 5. the run page draws the curves and shows the numbers
    page.goto(f"{live_server}/runs/{run_id}")
    expect(page.locator("#run-status")).to_contain_text("training")
    expect(page.locator("#stat-success")).to_have_text("75%")
    expect(page.locator("#stat-speed")).to_have_text("85")
    expect(page.locator("#stat-step")).to_contain_text("6k / 20k")
    expect(page.locator("#chart-success path.series")).to_have_count(1)
    expect(page.locator("#chart-logits path.series")).to_have_count(2)
    expect(page.locator("#chart-queries path.series")).to_have_count(3)
    path = page.locator("#chart-success path.series").get_attribute("d") or ""
    assert path.startswith("M") and path.count("L") == 5
    expect(page.locator("#chart-success .chart-legend")).to_contain_text("75%")
    expect(page.locator("#rollout")).to_have_js_property("complete", True)
    expect(page.locator("#rollout-caption")).to_contain_text("8 frames")
    expect(page.locator("#answered figure")).to_have_count(2)
    expect(page.locator("#events")).to_contain_text("claimed by test-learner")
    expect(page.locator("#reward-verdict")).to_be_visible(timeout=15_000)  # the verdict on the reward's health
    expect(page.locator("#verdict-level")).to_have_text("learning")
    expect(page.locator("#verdict-summary")).to_contain_text("eval success reached 75%")

    # more metrics appear without a reload (the page polls with since_step)
    store.record_metrics(run_id=run_id, step=7000, values={"eval/success_rate": 0.9})
    expect(page.locator("#chart-success .chart-legend")).to_contain_text("90%", timeout=10_000)
    expect(page.locator("#stat-success")).to_have_text("90%", timeout=10_000)
    _shot(page, "05-run")

    page.click("#stop-run")
    expect(page.locator("#run-status")).to_contain_text("stopping")
    assert store.get_run(run_id=run_id).stop_requested is True

    page.goto(live_server)
    expect(page.locator(f'tr[data-run-id="{run_id}"]')).to_contain_text("VisualPusher-v0")
    _shot(page, "06-runs")
    assert errors == []


def test_with_a_token_pages_need_the_login_and_logout_ends_it(
    page: Page, make_live_server: Callable[..., LiveServer], store: Store
) -> None:
    """Reads need the token too: a page sends the browser to /login and back; Log out ends the session."""
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.on("console", lambda message: errors.extend([message.text] if "Security Policy" in message.text else []))
    server = make_live_server(RAQ_API_TOKEN="browser-token")
    store.create_goal_set(name="behind the login")
    page.goto(f"{server.url}/goal-sets")
    expect(page).to_have_url(re.compile(r"/login\?next=%2Fgoal-sets$"))
    page.fill("#token", "wrong")
    page.click("button[type=submit]")
    expect(page.locator(".alert.error")).to_contain_text("not right")
    page.fill("#token", "browser-token")
    page.click("button[type=submit]")
    expect(page).to_have_url(re.compile(r"/goal-sets$"))
    expect(page.get_by_text("behind the login")).to_be_visible()
    assert store.count_sessions() == 1
    page.click("text=Log out")
    expect(page).to_have_url(re.compile(r"/login$"))
    assert store.count_sessions() == 0
    page.goto(f"{server.url}/")
    expect(page).to_have_url(re.compile(r"/login\?next=%2F$"))
    assert errors == []


def test_page_scripts_are_modules_and_show_markup_as_text(page: Page, live_server: str, store: Store) -> None:
    """The style guide: page scripts are ES modules that import what they use (no shared globals) and build the DOM
    with textContent, never from HTML strings: a run name, failure reason or event holding markup shows as text."""
    root = Path(__file__).resolve().parent.parent
    for script in (root / "static").glob("*.js"):
        assert not re.search(r"innerHTML|outerHTML|insertAdjacentHTML|document\.write", script.read_text()), script.name
    tags = [
        tag for template in (root / "templates").glob("*.html")
        for tag in re.findall(r'<script\b[^>]*\bsrc="/static/[^>]*>', template.read_text())
    ]  # fmt: skip
    assert tags and all('type="module"' in tag for tag in tags), tags

    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    markup = '<img src="x" class="injected"> & <b>bold</b>'
    run = store.create_run(env_id="VisualPusher-v0", algorithm="vice_raq", config={}, name=markup)
    store.set_run_status(run_id=run.id, status=RunStatus.FAILED, reason=markup)
    store.record_event(run_id=run.id, message=markup, level="error")
    page.goto(live_server)
    row = page.locator(f'tr[data-run-id="{run.id}"]')
    expect(row).to_contain_text(markup)
    expect(row.locator(".reason")).to_have_text(markup)
    expect(row.locator(".status")).to_have_attribute("title", markup)
    page.goto(f"{live_server}/runs/{run.id}")
    expect(page.locator("#events li.error span").first).to_have_text(markup)
    expect(page.locator("#run-status .status")).to_have_attribute("title", markup)
    expect(page.locator(".injected")).to_have_count(0)
    assert errors == []
