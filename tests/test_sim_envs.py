"""The simulated tasks as Gymnasium envs: API conformance, determinism, success thresholds, and what the camera sees.

Real MuJoCo physics and rendering (MUJOCO_GL=egl by default), no mocks.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import warnings
from collections.abc import Iterator

import gymnasium
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from PIL import Image

import sim
from sim.door import VisualDoorEnv
from sim.picker import VisualPickerEnv
from sim.pusher import VisualPusherEnv
from sim.scripted import DRAPE_WAYPOINTS, draping_action

ENV_IDS = list(sim.TASKS.values())
ACTION_DIMS = {
    "VisualPusher-v0": 2, "VisualDoor-v0": 3, "VisualPicker-v0": 4, "VisualBookshelf-v0": 2, "VisualDraping-v0": 2,
}  # fmt: skip
FIRST_ACTION_AXIS = {"VisualDraping-v0": 1}
"""The hand's axis the first action dimension moves, where it is not x (draping: y, toward the box's far side)."""
# Just inside / just outside a threshold.
EPS = 1e-4


@pytest.fixture
def make_env() -> Iterator:
    made: list[gymnasium.Env] = []

    def _make(env_id: str, **kwargs) -> gymnasium.Env:
        env = gymnasium.make(env_id, **kwargs)
        made.append(env)
        return env

    yield _make
    for env in made:
        env.close()


def changed_fraction(a: np.ndarray, b: np.ndarray, threshold: int = 30) -> float:
    """Fraction of pixels whose largest channel difference exceeds `threshold`."""
    return float((np.abs(a.astype(int) - b.astype(int)).max(axis=-1) > threshold).mean())


def test_import_registers_the_tasks() -> None:
    assert sim.TASKS == {
        "pusher": "VisualPusher-v0", "door": "VisualDoor-v0", "picker": "VisualPicker-v0",
        "bookshelf": "VisualBookshelf-v0", "draping": "VisualDraping-v0",
    }  # fmt: skip
    for env_id in ENV_IDS:
        assert gymnasium.spec(env_id).max_episode_steps == 100


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("render_mode", [None, "rgb_array"])
def test_check_env_passes(env_id: str, render_mode: str | None, make_env) -> None:
    env = make_env(env_id, render_mode=render_mode)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_spaces_step_and_info(env_id: str, make_env) -> None:
    env = make_env(env_id)
    assert env.action_space.shape == (ACTION_DIMS[env_id],)
    assert env.observation_space.shape == (48, 48, 3)
    assert env.observation_space.dtype == np.uint8
    obs, info = env.reset(seed=0)
    assert obs.shape == (48, 48, 3) and obs.dtype == np.uint8
    assert info["success"] == 0.0 and "hand_pos" in info
    env.action_space.seed(0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert env.observation_space.contains(obs)
    assert reward == info["success"] and isinstance(reward, float)
    assert not terminated and not truncated


def test_episode_is_truncated_after_100_steps(make_env) -> None:
    env = make_env("VisualPusher-v0")
    env.reset(seed=0)
    for step in range(1, 101):
        _, _, terminated, truncated, _ = env.step(np.zeros(2, dtype=np.float32))
        assert not terminated
        assert truncated == (step == 100)


def test_image_size_and_render_size_kwargs(make_env) -> None:
    env = make_env("VisualPusher-v0", image_size=84, render_mode="rgb_array", render_size=128)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (84, 84, 3)
    assert env.observation_space.shape == (84, 84, 3)
    frame = env.render()
    assert frame.shape == (128, 128, 3) and frame.dtype == np.uint8
    door = make_env("VisualDoor-v0", render_mode="rgb_array")
    door.reset(seed=0)
    assert door.render().shape == (256, 256, 3)
    no_render = make_env("VisualDoor-v0")
    no_render.reset(seed=0)
    assert no_render.render() is None


def test_display_view_shows_the_same_state_as_the_observation(make_env) -> None:
    env = make_env("VisualPusher-v0", render_mode="rgb_array")
    obs, _ = env.reset(seed=3)
    display = env.unwrapped.render_display()
    assert np.array_equal(display, env.render())
    small = np.asarray(Image.fromarray(display).resize((48, 48), Image.Resampling.BILINEAR), dtype=int)
    assert np.abs(small - obs.astype(int)).mean() < 12


def test_close_frees_renderers(make_env) -> None:
    env = make_env("VisualPicker-v0", render_mode="rgb_array")
    env.reset(seed=0)
    env.render()
    assert len(env.unwrapped._renderers) == 2
    env.close()
    assert env.unwrapped._renderers == {}


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_seeded_resets_are_deterministic(env_id: str, make_env) -> None:
    first, second = make_env(env_id), make_env(env_id)
    obs_a, info_a = first.reset(seed=123)
    obs_b, info_b = second.reset(seed=123)
    assert np.array_equal(obs_a, obs_b)
    actions = [np.full(ACTION_DIMS[env_id], 0.5, dtype=np.float32)] * 5
    for action in actions:
        obs_a, *_ = first.step(action)
        obs_b, *_ = second.step(action)
    assert np.array_equal(obs_a, obs_b)


def test_resets_randomise_the_start_through_the_seed(make_env) -> None:
    env = make_env("VisualPusher-v0")
    mugs = np.array([env.reset(seed=seed)[1]["mug_pos"] for seed in range(40)])
    hands = np.array([env.reset(seed=seed)[1]["hand_pos"] for seed in range(5)])
    assert np.all(mugs >= [-0.1, -0.05]) and np.all(mugs <= [0.1, 0.1])
    assert np.ptp(mugs[:, 0]) > 0.12 and np.ptp(mugs[:, 1]) > 0.08
    assert np.allclose(hands, hands[0])

    door = make_env("VisualDoor-v0")
    angles = np.array([door.reset(seed=seed)[1]["door_angle"] for seed in range(40)])
    closed = angles == 0.0
    assert 8 <= closed.sum() <= 32
    assert np.all(angles[~closed] > 0) and np.all(angles <= 0.3) and angles.max() > 0.2

    picker = make_env("VisualPicker-v0")
    balls = np.array([picker.reset(seed=seed)[1]["ball_pos"] for seed in range(40)])
    assert np.all(np.abs(balls[:, :2]) <= 0.05) and np.ptp(balls[:, 0]) > 0.06
    assert np.allclose(balls[:, 2], 0.03)


def test_pusher_success_flips_at_3_cm(make_env) -> None:
    env: VisualPusherEnv = make_env("VisualPusher-v0").unwrapped
    env.reset(seed=0)
    goal = env.goal_pos
    for direction in (np.array([1.0, 0.0]), np.array([0.6, -0.8])):
        env.set_mug_pos(goal + (0.03 - EPS) * direction)
        info = env.get_info()
        assert info["success"] == 1.0 and info["mug_to_goal"] == pytest.approx(0.03 - EPS)
        env.set_mug_pos(goal + (0.03 + EPS) * direction)
        assert env.get_info()["success"] == 0.0


def test_door_success_flips_at_45_degrees_plus_minus_0_1_rad(make_env) -> None:
    env: VisualDoorEnv = make_env("VisualDoor-v0").unwrapped
    env.reset(seed=0)
    target = np.pi / 4
    for sign in (-1.0, 1.0):
        env.set_door_angle(target + sign * (0.1 - EPS))
        info = env.get_info()
        assert info["success"] == 1.0 and info["door_angle"] == pytest.approx(target + sign * (0.1 - EPS))
        env.set_door_angle(target + sign * (0.1 + EPS))
        assert env.get_info()["success"] == 0.0


def test_picker_success_flips_at_3_cm_from_the_point_20_cm_above_the_table(make_env) -> None:
    env: VisualPickerEnv = make_env("VisualPicker-v0").unwrapped
    env.reset(seed=0)
    goal = env.goal_pos
    assert goal[2] == pytest.approx(0.2)
    for direction in (np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.6, -0.8])):
        env.set_ball_pos(goal + (0.03 - EPS) * direction)
        info = env.get_info()
        assert info["success"] == 1.0 and info["ball_to_goal"] == pytest.approx(0.03 - EPS)
        env.set_ball_pos(goal + (0.03 + EPS) * direction)
        assert env.get_info()["success"] == 0.0


def test_camera_sees_the_objects_move(make_env) -> None:
    pusher: VisualPusherEnv = make_env("VisualPusher-v0").unwrapped
    pusher.reset(seed=0)
    before = pusher.render_image(48)
    pusher.set_mug_pos(pusher.mug_pos + np.array([0.06, 0.0]))
    assert changed_fraction(before, pusher.render_image(48)) > 0.01

    door: VisualDoorEnv = make_env("VisualDoor-v0").unwrapped
    door.reset(seed=0)
    door.set_door_angle(0.0)
    before = door.render_image(48)
    door.set_door_angle(0.1)  # a small opening is plain at 48 x 48
    assert changed_fraction(before, door.render_image(48)) > 0.05
    door.set_door_angle(np.pi / 4)
    assert changed_fraction(before, door.render_image(48)) > 0.15

    picker: VisualPickerEnv = make_env("VisualPicker-v0").unwrapped
    picker.reset(seed=0)
    before = picker.render_image(48)
    picker.set_ball_pos(picker.ball_pos + np.array([0.0, 0.0, 0.1]))
    assert changed_fraction(before, picker.render_image(48)) > 0.01


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_actions_move_the_hand_2_cm_per_unit_inside_the_workspace(env_id: str, make_env) -> None:
    env = make_env(env_id)
    env.reset(seed=0)
    task_env = env.unwrapped
    start = task_env.hand_pos
    action = np.zeros(ACTION_DIMS[env_id], dtype=np.float32)
    action[0] = 1.0
    for _ in range(2):
        env.step(action)
    env.step(np.zeros_like(action))
    moved = task_env.hand_pos - start
    axis = FIRST_ACTION_AXIS.get(env_id, 0)
    assert moved[axis] == pytest.approx(0.04, abs=0.004)
    assert np.abs(np.delete(moved, axis)).max() < 0.003
    for _ in range(40):
        env.step(-np.ones_like(action))
    assert np.all(task_env.hand_pos >= np.array(task_env.hand_low) - 0.003)


def test_pusher_hand_height_is_fixed(make_env) -> None:
    env = make_env("VisualPusher-v0")
    env.reset(seed=0)
    env.action_space.seed(1)
    heights = [env.step(env.action_space.sample())[4]["hand_pos"][2] for _ in range(30)]
    assert np.allclose(heights, VisualPusherEnv.hand_height, atol=0.002)


def test_door_hook_catches_the_handle_and_a_straight_pull_opens_the_door(make_env) -> None:
    env: VisualDoorEnv = make_env("VisualDoor-v0").unwrapped
    env.reset(seed=0)
    env.set_door_angle(0.0)
    # The hand starts over the handle in x: straight to the far y-limit, then down, and the tip is in the slot.
    assert env.slot_along(env.hand_pos)[0] == pytest.approx(0.22, abs=0.01)
    for action in [(0.0, 1.0, 0.0)] * 18 + [(0.0, 0.0, -1.0)] * 14:
        env.step(np.array(action, dtype=np.float32))
    assert env.is_hooked() and env.door_angle < 0.02
    # A straight pull back along -y at a fixed x opens the door past 45 degrees with the tip still behind the bar.
    angles = []
    for _ in range(12):
        angles.append(env.step(np.array([0.0, -1.0, 0.0], dtype=np.float32))[4]["door_angle"])
        if angles[-1] > np.pi / 4:
            break
    assert angles[-1] > np.pi / 4 and env.is_hooked()
    assert np.all(np.diff(angles) > 0)


def test_door_hinge_stops_at_60_degrees_and_the_tip_cannot_pass_through_the_bar(make_env) -> None:
    env: VisualDoorEnv = make_env("VisualDoor-v0").unwrapped
    env.reset(seed=0)
    env.set_door_angle(0.0)
    # Above the bar's height but below its top the hook runs into the bar instead of reaching the slot.
    env.set_hand_pos(np.array([-0.05, -0.1, 0.15]))
    for _ in range(20):
        env.step(np.array([0.0, 1.0, 0.0], dtype=np.float32))
    assert env.hand_pos[1] < env.handle_pos[1] - 0.01 and not env.is_hooked()
    env.set_door_angle(1.2)
    mujoco.mj_step(env.model, env.data, nstep=200)
    assert env.door_angle <= np.radians(60) + 0.02


def test_picker_ball_stays_in_its_region_and_the_gripper_holds_it(make_env) -> None:
    env: VisualPickerEnv = make_env("VisualPicker-v0").unwrapped
    env.reset(seed=0)
    env.set_ball_pos(np.array([0.049, 0.0, env.ball_radius]))
    env.set_hand_pos(np.array([0.0, 0.0, 0.03]))
    # Sweeping the hand (fingers open) across the ball pushes it to the region's edge and no further.
    env.set_hand_pos(np.array([-0.05, 0.0, 0.03]))
    for _ in range(10):
        info = env.step(np.array([1.0, 0.0, 0.0, -1.0], dtype=np.float32))[4]
    assert np.all(np.abs(info["ball_pos"][:2]) <= env.ball_half_range + 1e-9)
    # Down over the ball, close, lift: the ball comes up with the hand.
    ball = info["ball_pos"]
    env.set_hand_pos(np.array([ball[0], ball[1], 0.2]))
    for _ in range(20):
        offset = (np.array([ball[0], ball[1], ball[2]]) - env.hand_pos) / env.action_scale
        env.step(np.append(np.clip(offset, -1, 1), -1.0).astype(np.float32))
    for _ in range(5):
        env.step(np.array([0.0, 0.0, 0.0, 1.0], dtype=np.float32))
    for _ in range(8):
        info = env.step(np.array([0.0, 0.0, 1.0, 1.0], dtype=np.float32))[4]
    assert info["ball_pos"][2] > 0.15 and info["gripper_opening"] == pytest.approx(2 * env.ball_radius, abs=0.01)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_a_state_snapshot_renders_that_state_later_and_leaves_the_simulation_as_it_was(env_id: str, make_env) -> None:
    shown, twin = make_env(env_id, render_mode="rgb_array"), make_env(env_id, render_mode="rgb_array")
    shown.reset(seed=4)
    twin.reset(seed=4)
    shown.action_space.seed(4)
    actions = [shown.action_space.sample() for _ in range(30)]
    for action in actions[:10]:
        shown.step(action)
        twin.step(action)
    snapshot = shown.unwrapped.state_snapshot()
    then = shown.render()
    for action in actions[10:20]:
        shown.step(action)
        twin.step(action)
    assert not np.array_equal(shown.render(), then)
    now = shown.unwrapped.state_snapshot()
    shown.unwrapped.restore_snapshot(snapshot)
    assert np.array_equal(shown.render(), then)
    shown.unwrapped.restore_snapshot(now)
    for action in actions[20:]:  # the simulation goes on exactly as if nothing had been rendered in between
        obs_shown, *_, info_shown = shown.step(action)
        obs_twin, *_, info_twin = twin.step(action)
        assert np.array_equal(obs_shown, obs_twin)
    assert np.array_equal(info_shown["hand_pos"], info_twin["hand_pos"])


def test_the_held_book_goes_down_into_either_empty_slot_and_nowhere_else(make_env) -> None:
    """Lowered over an empty slot the book goes in (a success, in either slot); over a standing book, or between
    two, it stops on top (no success)."""
    env = make_env("VisualBookshelf-v0").unwrapped
    reached = {}
    for x in (*env.slot_x, 0.0, 0.02, -0.14):
        env.reset(seed=0)
        env.set_hand_pos(np.array([x, env.shelf_y, env.hand_init[2]]))
        for _ in range(30):
            _, _, _, _, info = env.step(np.array([0.0, -1.0]))
        reached[round(float(x), 2)] = (info["success"], round(info["book_bottom"], 2))
    assert reached[-0.08][0] == reached[0.08][0] == 1.0
    assert {reached[x][0] for x in (0.0, 0.02, -0.14)} == {0.0}
    assert min(reached[x][1] for x in (0.0, 0.02, -0.14)) >= 0.14  # (on top of the row: 14.4-16 cm)


def test_the_cloth_laid_over_the_box_is_draped_and_the_straight_line_to_the_same_end_is_not(make_env) -> None:
    """The scripted hand lifts the cloth, lays it over the near edge and draws it across: it lies on the top and
    hangs down both sides, unfolded. The shortest way to the very same end point (what a reward on the end
    effector's distance asks for: straight to above it, clear of the box, then down) drags it across the top, its
    free edge left out on the table: no success."""
    env = make_env("VisualDraping-v0").unwrapped
    end = np.array(env.hand_goal)
    assert np.array_equal(end, DRAPE_WAYPOINTS[-1])
    for seed in range(3):
        env.reset(seed=seed)
        for _ in range(40):
            _, _, _, _, laid = env.step(draping_action(env))
        env.reset(seed=seed)
        for target in (end + [0.0, 0.04], end):  # (straight to above the end, the gripper clearing the box; down)
            for _ in range(25):
                _, _, _, _, dragged = env.step(np.clip((target - env.hand_pos[1:]) / env.action_scale, -1.0, 1.0))
        assert np.allclose(env.hand_pos[1:], end, atol=0.005)
        assert laid["success"] == 1.0 and laid["covering"] >= env.covering_vertices and laid["fold"] <= 0.05
        assert laid["near_hang"] == laid["far_hang"] == 1.0
        assert dragged["success"] == 0.0 and dragged["near_hang"] == 0.0  # (its free edge out on the table)
        # the hand-made reward on the end effector is at its best on the straight path, which drapes nothing
        assert dragged["hand_distance"] < 0.005 and laid["hand_distance"] < 0.01
