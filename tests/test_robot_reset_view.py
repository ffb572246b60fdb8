"""While the actor waits for the person's first scene reset, the reset card's live view is the robot camera's:
the actor (robot/drive/actor.py) of a stand-in robot run, before its env was ever reset, refreshes its frame from the
camera (rendered by MuJoCo) and would publish it to the store."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np

from contract.actor_messages import ActorSettings
from contract.config import TrainConfig
from contract.envs import display_image, make_env
from learner.acting import SAC_ACTING
from robot.drive.actor import ActorLoop

STANDIN = "robot.standin:PusherStandIn-v0"


def test_before_the_first_reset_the_live_view_is_the_robot_camera(database_url: str) -> None:
    config = TrainConfig(env_id=STANDIN, image_size=48, display_size=128, control_hz=5.0)
    settings = ActorSettings(
        config=config.to_dict(), run_id=1, database_url=database_url, control_hz=5.0, person_reset=True
    )
    loop = ActorLoop(settings, connection=None, outbox=None, acting=SAC_ACTING)
    try:
        assert loop.frame is None  # nothing seen yet: the env has not been reset
        loop._refresh_frame()
        assert loop.frame is not None, "the live view stays empty until the first episode"
        assert loop.frame.shape == (384, 512, 3)  # the camera's whole 4:3 frame
        camera = loop.env.unwrapped.read_camera()
        assert np.array_equal(loop.frame, camera)
    finally:
        loop.env.close()


def test_a_person_can_look_at_an_env_before_its_first_reset() -> None:
    env = make_env(STANDIN, image_size=48, display_size=128)
    try:
        view = display_image(env, 128, None)
        assert view.shape == (96, 128, 3) and view.dtype == np.uint8
    finally:
        env.close()
