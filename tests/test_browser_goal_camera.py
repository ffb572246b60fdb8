"""Goals from the robot's own camera on the goal-set page, in Debian's Chromium against a real server (the real
stand-in robot rendering with MuJoCo, MUJOCO_GL=egl by default) and SQLite: the live view, Capture by button and
by key, and a photo that differs from the camera shown beside it before it is used (Discard, Use anyway)."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import io
import re
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from conftest import STANDIN, robot_serving
from PIL import Image
from playwright.sync_api import Page, expect
from test_browser import _scene, _shot
from test_browser_daily_use import watch

from contract.store import Store

pytestmark = pytest.mark.browser


@pytest.fixture(autouse=True)
def standin(store: Store, tmp_path: Path) -> Iterator[None]:
    """The stand-in robot's own process, up: it alone opens the camera."""
    with robot_serving(store, STANDIN, tmp_path / "checkpoints"):
        yield


def _box(page: Page, selector: str) -> dict:
    box = page.locator(selector).bounding_box()
    assert box is not None, selector
    return box


def test_capture_from_the_robot_camera_and_a_photo_unlike_it_shown_beside_it(
    desktop: Page, live_server: str, store: Store, tmp_path: Path
) -> None:
    page = desktop
    problems = watch(page, live_server)
    goal_set = store.create_goal_set(name="mug on the coaster", env_id=STANDIN, image_size=48)
    frames: list[str] = []
    page.on("response", lambda r: frames.extend([r.url] if "/api/cameras/frame" in r.url else []))

    # the Camera panel opens on the set's robot and shows its live view, refreshed about twice a second
    page.goto(f"{live_server}/goal-sets/{goal_set.id}")
    expect(page.locator("#camera-env")).to_have_value(STANDIN)
    expect(page.locator("#camera-live")).to_have_js_property("naturalWidth", 512)
    expect(page.locator("#camera-live")).to_have_js_property("naturalHeight", 384)
    expect(page.locator("#camera-status")).to_contain_text("live")
    seen = len(frames)
    page.wait_for_timeout(1600)
    assert len(frames) >= seen + 2, frames
    _shot(page, "16-01-goal-set-camera-live")

    # Capture, by the button and by the key C: goal photos from the camera, shown at once
    page.click("#camera-capture")
    expect(page.locator("#examples .example")).to_have_count(1)
    expect(page.locator("#examples .example .source-tag")).to_have_text("camera")
    expect(page.locator("#examples .example img.model")).to_have_js_property("naturalWidth", 48)
    expect(page.locator("#examples .example figcaption").nth(1)).to_have_text("original (512×384)")
    expect(page.locator("#goal-photo-advice")).to_contain_text("1 photo: too few")
    expect(page.locator("#goal-set-photo-total")).to_have_text("1 photo")  # the header counts it, no reload
    page.locator("body").press("c")
    expect(page.locator("#examples .example")).to_have_count(2)
    expect(page.locator("#goal-set-photo-total")).to_have_text("2 photos")
    examples = store.list_goal_examples(goal_set_id=goal_set.id)
    assert [(e.source, e.width, e.height) for e in examples] == [("camera", 512, 384)] * 2
    _shot(page, "16-02-goal-set-captured")

    # C typed into a field is a letter, and Ctrl+C a copy: no capture
    page.reload()
    expect(page.locator("#examples .example .source-tag")).to_have_count(2)
    field = page.locator("#framing-env")
    field.press("End")
    field.press("c")
    expect(field).to_have_value(STANDIN + "c")
    field.press("Backspace")  # back to the set's task before the Framing panel asks for it
    page.locator("body").press("Control+c")
    page.wait_for_timeout(500)
    assert len(store.list_goal_examples(goal_set_id=goal_set.id)) == 2

    # a square, small photo: the warning says how it differs, with the photo beside the camera's frame
    square = tmp_path / "square.png"
    square.write_bytes(_scene(48, (74, 74)))
    page.set_input_files("#goal-files", [str(square)])
    warning = page.locator(".photo-warning")
    expect(warning).to_have_count(1)
    expect(warning).to_contain_text("square.png does not look like the robot camera's view")
    expect(warning.locator("li[data-kind=aspect]")).to_contain_text("the photo is 48×48 (square)")
    expect(warning.locator("li[data-kind=size]")).to_be_visible()
    expect(warning.locator("img.photo")).to_have_js_property("naturalWidth", 48)
    expect(warning.locator("img.camera")).to_have_js_property("naturalWidth", 512)
    photo, frame = _box(page, ".photo-warning img.photo"), _box(page, ".photo-warning img.camera")
    assert photo["x"] + photo["width"] <= frame["x"] and abs(photo["y"] - frame["y"]) < 40  # side by side
    assert len(store.list_goal_examples(goal_set_id=goal_set.id)) == 2  # nothing used yet
    _shot(page, "16-03-goal-set-photo-warning")

    # Discard adds nothing
    warning.get_by_role("button", name="Discard").click()
    expect(page.locator(".photo-warning")).to_have_count(0)
    expect(page.locator("#upload-status")).to_contain_text("Discarded square.png")
    assert len(store.list_goal_examples(goal_set_id=goal_set.id)) == 2
    expect(page.locator("#examples .example")).to_have_count(2)

    # Use anyway adds it
    page.set_input_files("#goal-files", [str(square)])
    page.locator(".photo-warning").get_by_role("button", name="Use anyway").click()
    expect(page.locator(".photo-warning")).to_have_count(0)
    expect(page.locator("#examples .example")).to_have_count(3)
    stored = store.list_goal_examples(goal_set_id=goal_set.id)
    assert [(e.source, e.filename) for e in stored][-1] == ("upload", "square.png")

    # a photo that looks like the camera's view is uploaded at once
    like = tmp_path / "like-the-camera.png"
    response = httpx.get(f"{live_server}/api/cameras/frame", params={"env_id": STANDIN}, timeout=30)
    with Image.open(io.BytesIO(response.content)) as image:
        image.convert("RGB").save(like, format="PNG")
    page.set_input_files("#goal-files", [str(like)])
    expect(page.locator("#examples .example")).to_have_count(4)
    expect(page.locator(".photo-warning")).to_have_count(0)
    assert [e.filename for e in store.list_goal_examples(goal_set_id=goal_set.id)][-1] == "like-the-camera.png"
    assert problems == [], problems


def test_a_set_of_no_robot_task_offers_the_cameras_and_opens_none(
    desktop: Page, live_server: str, store: Store, tmp_path: Path
) -> None:
    page = desktop
    problems = watch(page, live_server)
    goal_set = store.create_goal_set(name="any task")
    page.goto(f"{live_server}/goal-sets/{goal_set.id}")
    expect(page.locator("#camera-env option", has_text=STANDIN)).to_have_count(1)
    expect(page.locator("#camera-env")).to_have_value("")
    expect(page.locator("#camera-capture")).to_be_disabled()
    expect(page.locator("#camera-view")).to_be_hidden()
    page.locator("body").press("c")
    # a photo is uploaded unchecked: the set has no robot camera and none is chosen
    photo = tmp_path / "goal.png"
    photo.write_bytes(_scene(48, (74, 74)))
    with page.expect_response(re.compile(r"/api/goal-sets/\d+/examples$")):
        page.set_input_files("#goal-files", [str(photo)])
    expect(page.locator("#examples .example")).to_have_count(1)
    assert [e.source for e in store.list_goal_examples(goal_set_id=goal_set.id)] == ["upload"]

    # choosing the robot shows its camera; Capture then adds its frame
    page.select_option("#camera-env", STANDIN)
    expect(page.locator("#camera-live")).to_have_js_property("naturalWidth", 512)
    page.click("#camera-capture")
    expect(page.locator("#examples .example")).to_have_count(2)
    assert [e.source for e in store.list_goal_examples(goal_set_id=goal_set.id)] == ["upload", "camera"]
    assert problems == [], problems
