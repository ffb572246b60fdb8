"""A robot whose camera opens in one process at a time (most USB cameras), owned by its own process (`raq robot`),
with the goal-set page's live view open on a server of its own: a run of it is created and starts, the robot's
process drives it, the page goes on showing frames, and nothing but the robot's process opens the camera or moves
or holds the arm, previews and the learner included."""

import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
from conftest import robot_subprocess, run_live_server
from recording_arm import EXCLUSIVE_ENV_ID, recorded_by
from test_actor import ROOT, arm_env, real_time_config, wait_for

from contract.settings import Settings
from contract.store import RunStatus, Store

MOVES = ("action", "reset", "hold")
"""What the arm's log says when something moved or held it."""


def test_a_run_starts_while_the_camera_panel_is_open_and_only_the_robots_process_touches_the_robot(
    dot_reach: tuple[Settings, Store, int], tmp_path: Path
) -> None:
    settings, store, goal_set_id = dot_reach
    log = tmp_path / "arm.log"
    robot_env = arm_env(settings, log)
    server_env = {key: robot_env[key] for key in ("RAQ_ENV_MODULES", "PYTHONPATH", "RECORDING_ARM_LOG")}
    with (
        run_live_server(store.url, tmp_path, server_env) as server,
        robot_subprocess(robot_env, EXCLUSIVE_ENV_ID, store, tmp_path / "robot.log") as robot,
    ):
        frames = httpx.Client(base_url=server.url, timeout=120)
        first = frames.get("/api/cameras/frame", params={"env_id": EXCLUSIVE_ENV_ID})
        assert first.status_code == 200, first.text  # the live view: the robot's process publishes its frames
        assert first.headers["x-camera-source"].startswith("robot ")
        answers: list[int] = []
        panel_open = threading.Event()
        panel_open.set()

        def camera_panel() -> None:  # the page asks for a frame five times a second
            while panel_open.is_set():
                answers.append(frames.get("/api/cameras/frame", params={"env_id": EXCLUSIVE_ENV_ID}).status_code)
                time.sleep(0.2)

        viewer = threading.Thread(target=camera_panel, daemon=True)
        viewer.start()
        preview = frames.get("/api/envs/preview", params={"env_id": EXCLUSIVE_ENV_ID, "size": 16})
        assert preview.status_code == 200, preview.text  # the camera's frame, never a reset
        config = real_time_config(
            env_id=EXCLUSIVE_ENV_ID, control_hz=10.0, total_steps=100_000, reset_every_episode=False,
            episode_steps=1000,
        )  # fmt: skip
        created = frames.post(
            "/api/runs", json={"env_id": EXCLUSIVE_ENV_ID, "goal_set_id": goal_set_id, "config": config.to_dict(),
                               "confirm_env_mismatch": True},
        )  # fmt: skip
        assert created.status_code == 201, created.text  # not "device busy"
        run_id = created.json()["id"]
        learner = subprocess_learner(robot_env)
        try:
            wait_for(lambda: moves(log, "action") >= 5 or learner.poll() is not None, 180, "the arm to move")
            assert learner.poll() is None, learner.communicate(timeout=30)[0].decode()
            assert store.get_run(run_id=run_id).status == RunStatus.TRAINING
            asked = len(answers)
            wait_for(lambda: answers[asked:].count(200) >= 3, 10, "the live view to show the actor's frames")
            again = frames.get("/api/envs/preview", params={"env_id": EXCLUSIVE_ENV_ID, "size": 16})
            assert again.status_code == 200, again.text  # while the run acts: its actor's frame
        finally:
            panel_open.clear()
            viewer.join(timeout=10)
            store.request_stop(run_id=run_id)
            output = learner.communicate(timeout=120)[0].decode()
        assert learner.returncode is not None
        others = [(what, pid) for what, _, pid in recorded_by(log) if pid != robot.pid and what in (*MOVES, "open")]
        assert others == [], others  # not the server, not the learner
        assert any(what == "action" and pid == robot.pid for what, _, pid in recorded_by(log))
        assert "CameraBusy" not in output


def moves(log: Path, what: str) -> int:
    return sum(1 for kind, _, _ in recorded_by(log) if kind == what)


def subprocess_learner(env: dict[str, str]) -> subprocess.Popen:
    """`raq learn --once` in a process of its own, the robot's env variables set."""
    return subprocess.Popen(
        [sys.executable, "-m", "learner.worker", "--once", "--name", "handover"], cwd=ROOT, env=env,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
    )  # fmt: skip
