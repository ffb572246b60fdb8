"""Goal examples and scripted controllers of the simulated tasks (real MuJoCo rendering, no mocks)."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
import pytest
from PIL import Image

import sim
from sim.goals import GoalExample, main, make_goal_examples, write_goal_pngs
from sim.scripted import success_rate


@pytest.mark.parametrize("task", list(sim.TASKS))
def test_goal_examples_are_varied_successes_of_one_fixed_goal(task: str) -> None:
    examples = make_goal_examples(task, 3, seed=0, image_size=48, display_size=64)
    assert len(examples) == 3
    for example in examples:
        assert isinstance(example, GoalExample)
        assert example.info["success"] == 1.0
        assert example.image.shape == (48, 48, 3) and example.image.dtype == np.uint8
        assert example.display.shape == (64, 64, 3)
    images = [example.image for example in examples]
    assert all(not np.array_equal(images[0], other) for other in images[1:])
    if task == "door":
        assert all(abs(example.info["door_angle"] - np.pi / 4) <= 0.1 for example in examples)
        assert all(example.info["hooked"] == 1.0 for example in examples)  # the hook is still in the handle
    elif task == "bookshelf":  # either slot is a success: the examples show both
        slots = {example.info["slot"] for example in make_goal_examples(task, 8, seed=0, image_size=48)}
        assert slots == {0, 1}
    elif task == "draping":  # the cloth on the top and down both sides
        assert all(example.info["near_hang"] == example.info["far_hang"] == 1.0 for example in examples)
    else:
        goals = np.array([example.info["goal_pos"] for example in examples])
        assert np.array_equal(goals, np.repeat(goals[:1], len(goals), axis=0))


def test_goal_examples_are_reproducible_from_the_seed() -> None:
    first = make_goal_examples("pusher", 2, seed=5)
    second = make_goal_examples("pusher", 2, seed=5)
    assert all(np.array_equal(a.image, b.image) for a, b in zip(first, second, strict=True))
    mugs = np.array([example.info["mug_pos"] for example in make_goal_examples("pusher", 10, seed=1)])
    goal = sim.pusher.VisualPusherEnv.success_radius
    assert np.ptp(mugs, axis=0).max() > 0.005
    assert np.all(np.linalg.norm(mugs - [0.0, 0.17], axis=1) <= goal)


def test_write_goal_pngs_and_cli(tmp_path) -> None:
    paths = write_goal_pngs("pusher", 2, tmp_path / "goals", seed=0, image_size=48)
    assert [path.name for path in paths] == ["pusher_goal_00.png", "pusher_goal_01.png"]
    for path in paths:
        with Image.open(path) as image:
            assert image.size == (48, 48) and image.mode == "RGB"
    assert main(["--task", "picker", "-n", "1", "--out", str(tmp_path / "cli"), "--image-size", "32"]) == 0
    with Image.open(tmp_path / "cli" / "picker_goal_00.png") as image:
        assert image.size == (32, 32)
    with pytest.raises(SystemExit):
        main(["--task", "nonsense", "--out", str(tmp_path)])


@pytest.mark.parametrize("task", list(sim.TASKS))
def test_scripted_controller_solves_every_episode(task: str) -> None:
    assert success_rate(task, "scripted", episodes=20, seed=0) == 1.0


RANDOM_EPISODES = {"draping": 25}
"""Fewer random episodes where a step costs more (the cloth's contacts): none of them may succeed."""


@pytest.mark.parametrize("task", list(sim.TASKS))
def test_uniformly_random_actions_succeed_in_at_most_2_percent_of_episodes(task: str) -> None:
    assert success_rate(task, "random", episodes=RANDOM_EPISODES.get(task, 100), seed=0) <= 0.02
