"""The automated person of the stand-in bench: the scene as the stand-in shows it is enough for its hands (the
scripted expert) to put the mug on the coaster, and it helps often early and not at all late, unless the run
asks for help."""

from pathlib import Path

import numpy as np

from bench.helping_person import ASKED, OFTEN, TAPER_EPISODES, expert_action, help_chance
from bench.seen_standin import SEEN_VARIABLE, SeenStandIn, seen_state


def test_the_seen_scene_guides_the_hands_to_the_goal(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    seen = tmp_path / "seen.json"
    monkeypatch.setenv(SEEN_VARIABLE, str(seen))
    robot = SeenStandIn(image_size=48, camera_size=64)
    try:
        robot.arm(seconds=60.0)  # (a simulation of its own: no robot process here)
        successes = []
        for episode in range(3):
            robot.reset(seed=episode)
            for _ in range(100):
                state = seen_state(seen)
                assert state is not None and state["episode"] == episode + 1
                if state["success"]:
                    break
                robot.step(expert_action(state))
            successes.append(seen_state(seen)["success"])  # type: ignore[index]
        assert successes == [True, True, True]
    finally:
        robot.close()


def test_help_comes_often_early_then_tapers_to_none() -> None:
    chances = [help_chance(episode) for episode in range(1, 100)]
    assert chances[0] == OFTEN and chances[TAPER_EPISODES:] == [0.0] * len(chances[TAPER_EPISODES:])
    assert np.all(np.diff(chances) <= 0)
    assert help_chance(TAPER_EPISODES + 10, asked=True) == ASKED  # late, but the run asks for help
