"""The README's example env works as the README says: its module passes gymnasium's checker and the env maker's
checks under RAQ_ENV_MODULES, and its goal script draws ten photos of success."""

import subprocess
import sys
from pathlib import Path

from conftest import ROOT
from gymnasium.utils.env_checker import check_env
from PIL import Image

from contract.envs import env_id_problem, first_frames
from contract.settings import get_settings

EXAMPLES = ROOT / "examples"


def test_the_example_env_is_one_a_run_can_use(monkeypatch, request) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.syspath_prepend(str(EXAMPLES))
    monkeypatch.setenv("RAQ_ENV_MODULES", "my_robot")
    get_settings.cache_clear()  # the learner's env maker reads RAQ_ENV_MODULES through the cached settings
    request.addfinalizer(get_settings.cache_clear)
    import my_robot  # noqa: PLC0415 - importable once examples/ is on the path, as the README sets PYTHONPATH

    check_env(my_robot.Slide(), skip_render_check=True)
    assert env_id_problem("my_robot:Slide-v0", allowed_modules=["my_robot"]) is None
    assert env_id_problem("my_robot:Slide-v0", allowed_modules=[]) is not None
    observation, display, _ = first_frames("my_robot:Slide-v0", image_size=48, display_size=128)
    assert observation and display


def test_the_goal_script_draws_ten_photos_of_success(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, str(EXAMPLES / "make_goals.py")], cwd=tmp_path, capture_output=True,
                          text=True, env={"PYTHONPATH": str(EXAMPLES), "PATH": "/usr/bin:/bin"})  # fmt: skip
    assert done.returncode == 0, done.stderr
    photos = sorted(tmp_path.glob("goal*.png"))
    assert len(photos) == 10 and Image.open(photos[0]).size == (256, 256)
