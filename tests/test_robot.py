"""The robot contract: a camera over OpenCV read from a video file, observations made like goal photos, actions
clipped and limited in the env, moves refused unless the driver armed the env, stop() holding the arm and refusing
actions, one "is it a robot" check for a class, a factory function and a wrapper, and the simulated pusher behind the
contract as a stand-in robot that gymnasium's checker accepts. Where a test moves an arm it arms it first, as the
robot's own process does once the store says it may."""

import io
import time
from pathlib import Path

import cv2
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from PIL import Image

from contract.images import decode_upload, model_view, prepare_upload
from robot.base import RobotEnv, RobotNotArmed, RobotStopped, is_robot
from robot.camera import CameraError, OpenCVCamera

COLOURS = [(255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0)]


def write_video(path: Path, frames: int = 8, size: tuple[int, int] = (64, 48)) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, size)
    assert writer.isOpened()
    for index in range(frames):
        rgb = np.zeros((size[1], size[0], 3), dtype=np.uint8)
        rgb[:] = COLOURS[index % len(COLOURS)]
        writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    writer.release()


def test_the_camera_reads_a_video_file_as_rgb_frames_and_loops_by_default(tmp_path: Path) -> None:
    video = tmp_path / "camera.avi"
    write_video(video, frames=4)
    with OpenCVCamera(str(video)) as camera:
        frames = [camera.read() for _ in range(6)]
    assert all(frame.shape == (48, 64, 3) and frame.dtype == np.uint8 for frame in frames)
    for index, frame in enumerate(frames):  # RGB, not OpenCV's BGR; after the 4th frame it starts again
        assert np.abs(frame.mean(axis=(0, 1)) - COLOURS[index % 4]).max() < 20
    with OpenCVCamera(str(video), loop=False) as once:
        for _ in range(4):
            once.read()
        with pytest.raises(CameraError, match="gave no frame"):
            once.read()
    with pytest.raises(CameraError, match="cannot open"):
        OpenCVCamera(str(tmp_path / "missing.avi"))


class RecordingArm(RobotEnv):
    """A robot whose camera is a fixed 4:3 picture and whose arm records what it was sent."""

    needs_person_reset = False

    def __init__(self) -> None:
        super().__init__(action_dim=2, image_size=32)
        rng = np.random.default_rng(0)
        self.frame = rng.integers(0, 256, size=(120, 160, 3), dtype=np.uint8)
        self.sent: list[np.ndarray] = []
        self.holds = self.resets = 0

    def read_camera(self) -> np.ndarray:
        return self.frame

    def send_action(self, action: np.ndarray) -> None:
        self.sent.append(action)

    def reset_scene(self) -> None:
        self.resets += 1

    def hold_safe(self) -> None:
        self.holds += 1

    def limit_action(self, action: np.ndarray) -> np.ndarray:
        return np.minimum(action, 0.5)  # e.g. never faster than half speed forward


def test_actions_are_clipped_cleaned_and_limited_before_they_reach_the_arm() -> None:
    arm = RecordingArm()
    arm.arm(seconds=60)
    arm.reset()
    arm.step(np.array([3.0, -7.0]))
    arm.step(np.array([np.nan, 0.25]))
    assert [list(action) for action in arm.sent] == [[0.5, -1.0], [0.0, 0.25]]
    assert arm.sent[0].dtype == np.float32


class TimedArm(RecordingArm):
    """A robot whose speed limit takes the time since the previous action."""

    def __init__(self) -> None:
        super().__init__()
        self.told: list[float | None] = []

    def limit_action(self, action: np.ndarray, *, seconds: float | None = None) -> np.ndarray:
        self.told.append(seconds)
        return action


def test_limit_action_is_told_the_time_since_the_previous_action_where_it_takes_it() -> None:
    """One control period for the first action after a reset, then the real interval; an override written without
    `seconds` (RecordingArm's) is called as before."""
    arm = TimedArm()
    arm.arm(seconds=60)
    arm.reset()
    arm.step(np.zeros(2))
    time.sleep(0.05)
    arm.step(np.zeros(2))
    arm.reset()
    arm.step(np.zeros(2))
    first, later, after_reset = arm.told
    assert first == after_reset == 1.0 / arm.control_hz
    assert later is not None and 0.05 <= later < 0.2
    assert len(arm.sent) == 3


def test_the_observation_is_the_camera_frame_made_like_a_goal_photo() -> None:
    arm = RecordingArm()
    arm.arm(seconds=60)
    observation, info = arm.reset()
    assert observation.shape == (32, 32, 3) and observation.dtype == np.uint8 and info == {}
    png = io.BytesIO()
    Image.fromarray(arm.frame).save(png, format="PNG")
    goal = prepare_upload(png.getvalue(), filename="goal.png", model_size=32, max_bytes=10**7, max_pixels=10**7)
    assert np.array_equal(observation, np.asarray(Image.open(io.BytesIO(goal.model_png)).convert("RGB")))
    assert np.array_equal(observation, np.asarray(model_view(decode_upload(png.getvalue(), max_bytes=10**7,
                                                                           max_pixels=10**7), 32)))  # fmt: skip
    with pytest.raises(ValueError, match="expected \\(H, W, 3\\) uint8"):
        arm.observe(arm.frame.astype(np.float32))


def test_stop_holds_the_arm_and_refuses_actions_until_the_next_reset() -> None:
    arm = RecordingArm()
    arm.arm(seconds=60)
    arm.reset()
    arm.stop()
    assert arm.holds == 1
    with pytest.raises(RobotStopped):
        arm.step(np.zeros(2))
    assert arm.sent == []
    with pytest.raises(RobotNotArmed):  # (a stop disarms: the driver arms it again once the store says so)
        arm.reset()
    arm.arm(seconds=60)
    arm.reset()
    arm.step(np.zeros(2))
    assert len(arm.sent) == 1


def test_a_robot_nobody_armed_refuses_every_move_and_its_close_touches_nothing() -> None:
    """Made anywhere but by its driver (a preview, a lockstep runner, a script): reset and step raise before the arm
    is touched, and closing it holds nothing; an arming runs out, and disarm ends it at once."""
    arm = RecordingArm()
    with pytest.raises(RobotNotArmed, match="raq robot"):
        arm.reset()
    arm.stopped = False  # (even past a reset's state, a step asks the same)
    with pytest.raises(RobotNotArmed):
        arm.step(np.zeros(2))
    arm.stopped = True
    arm.close()
    assert arm.resets == 0 and arm.sent == [] and arm.holds == 0
    arm = RecordingArm()
    arm.arm(seconds=0.05)
    arm.reset()
    time.sleep(0.06)
    with pytest.raises(RobotNotArmed):
        arm.step(np.zeros(2))
    arm.arm(seconds=60)
    arm.step(np.zeros(2))
    arm.disarm()
    with pytest.raises(RobotNotArmed):
        arm.step(np.zeros(2))
    assert arm.resets == 1 and len(arm.sent) == 1


def make_arm(**kwargs: object) -> RecordingArm:
    """A robot registered through a factory function, as a lab wrapping its driver might."""
    return RecordingArm()


def test_is_robot_answers_for_a_class_a_made_env_under_wrappers_and_a_factory_functions_env() -> None:
    assert is_robot(RecordingArm) and not is_robot(int) and not is_robot(None)
    gym.register(id="LabWrappedArm-v0", entry_point=make_arm, max_episode_steps=10)
    try:
        env = gym.make("LabWrappedArm-v0")  # (a TimeLimit and an order enforcer around it)
        assert is_robot(env) and env is not env.unwrapped
        with pytest.raises(RobotNotArmed):
            env.reset()
        env.close()
        assert env.unwrapped.resets == 0 and env.unwrapped.holds == 0
        assert not is_robot(gym.make("CartPole-v1"))
    finally:
        del gym.registry["LabWrappedArm-v0"]


def test_the_stand_in_pusher_is_a_robot_env_gymnasium_accepts() -> None:
    env = gym.make("robot.standin:PusherStandIn-v0", image_size=48, camera_size=96)
    env.unwrapped.arm(seconds=600)
    check_env(env.unwrapped, skip_render_check=True)
    observation, info = env.reset(seed=0)
    assert observation.shape == (48, 48, 3) and info["success"] == 0.0
    frame = env.unwrapped.read_camera()
    assert frame.shape == (96, 128, 3)  # a 4:3 camera
    assert np.array_equal(observation, env.unwrapped.sim.render_image(48)) is False  # resized from the camera
    _, reward, terminated, truncated, info = env.step(np.ones(2, dtype=np.float32))
    assert reward == 0.0 and not terminated and not truncated and "success" in info
    assert env.spec.max_episode_steps == 100 and env.unwrapped.control_hz == 5.0
    env.close()
    assert env.unwrapped.held


def test_the_stand_ins_goal_photos_are_success_states_its_camera_sees_as_it_sees_observations() -> None:
    """robot.standin.goal_photos: camera frames of distinct success states (it keeps only those), whose model copy
    (as the Camera panel keeps a photo) is exactly the observation the stand-in makes of the same frame."""
    from robot.standin import PusherStandIn, goal_photos

    photos = goal_photos(3, seed=1, camera_size=96)
    assert len(photos) == 3 and all(photo.shape == (96, 128, 3) for photo in photos)
    assert not np.array_equal(photos[0], photos[1])  # different states
    robot = PusherStandIn(image_size=48, camera_size=96)
    try:
        for photo in photos:
            png = io.BytesIO()
            Image.fromarray(photo).save(png, format="PNG")
            kept = prepare_upload(png.getvalue(), filename="goal.png", model_size=48, max_bytes=10**7, max_pixels=10**7)
            assert np.array_equal(
                robot.observe(photo), np.asarray(Image.open(io.BytesIO(kept.model_png)).convert("RGB"))
            )
    finally:
        robot.close()
