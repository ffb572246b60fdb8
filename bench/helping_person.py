"""An automated person who helps a robot run with their hands, as HIL-SERL's guide says a person should: often in
the early episodes, then less and less. It sends what the run page sends, through the REST API: while it helps, the
scripted pusher expert's action (sim/scripted.py, on the scene as bench/seen_standin.py shows it) every half control
period (POST /api/runs/ID/robot/drive), and a hand-back once the mug is on the coaster or the episode ends.

In each episode it lets the policy act for a few steps first (0 to LATEST_START_STEPS, drawn), so the states it
takes over from vary; whether it helps at all is drawn per episode with `help_chance(episode, asked)`: `asked`
when the run asks for help (GET /api/runs/ID/robot: `asks_for_help`, no asked state a success lately).

With `demos`, it shows the way first instead and never takes over later: it presses Record demos (POST
/api/runs/ID/robot/demos) as soon as the robot's actor has reported, drives each demo episode from its first step
(whenever the robot says it waits for the person's keys) and presses the success key (POST
/api/runs/ID/robot/success) once the mug is on the coaster, which ends it.
"""

import contextlib
import json
import threading
import urllib.error
import urllib.request
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from bench.seen_standin import seen_state
from sim.pusher import VisualPusherEnv
from sim.scripted import pusher_action

OFTEN_EPISODES = 20
"""The first episodes, in each of which the person helps with probability OFTEN."""
OFTEN = 0.7
TAPER_EPISODES = 60
"""From OFTEN_EPISODES to this episode the chance falls linearly to 0; after it, no help."""
LATEST_START_STEPS = 20
"""The person takes over after 0 to this many of the policy's steps."""
ASKED = 0.3
"""The chance the person helps in an episode while the run asks for help (at least)."""


def help_chance(episode: int, asked: bool = False) -> float:
    """The chance the person helps in `episode` (the first is 1): OFTEN early, tapering to none; at least ASKED
    while the run asks for help."""
    if episode <= OFTEN_EPISODES:
        return OFTEN
    tapered = max(0.0, OFTEN * (TAPER_EPISODES - episode) / (TAPER_EPISODES - OFTEN_EPISODES))
    return max(tapered, ASKED) if asked else tapered


def expert_action(state: dict) -> np.ndarray:
    """The scripted pusher's action for the scene as seen."""
    scene = SimpleNamespace(
        mug_pos=np.asarray(state["mug"]), goal_pos=np.asarray(state["goal"]), hand_pos=np.asarray(state["hand"]),
        mug_radius=VisualPusherEnv.mug_radius, pusher_radius=VisualPusherEnv.pusher_radius,
        action_scale=VisualPusherEnv.action_scale,
    )  # fmt: skip
    return np.asarray(pusher_action(scene), dtype=float)  # type: ignore[arg-type]


def robot_status(url: str, run_id: int) -> dict:
    """The run's robot as the run page reads it (GET /api/runs/ID/robot); {} when the server cannot say."""
    try:
        with urllib.request.urlopen(f"{url}/api/runs/{run_id}/robot", timeout=5) as response:
            return json.loads(response.read())
    except (OSError, ValueError):
        return {}


def asks_for_help(url: str, run_id: int) -> bool:
    """Whether the run asks for a person's help now (False when the server cannot say)."""
    return bool(robot_status(url, run_id).get("asks_for_help"))


def waits_for_keys(url: str, run_id: int) -> bool:
    """Whether the robot waits for a person's keys now (a demo episode; False when the server cannot say)."""
    return str(robot_status(url, run_id).get("actor_state") or "").startswith("demo")


def post(url: str, body: dict | None = None) -> int:
    """POST `body` as JSON; the status code."""
    data = json.dumps(body or {}).encode()
    call = urllib.request.Request(url, method="POST", data=data, headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(call, timeout=5) as response:
            return response.status
    except urllib.error.HTTPError as error:
        return error.code


class HelpingPerson:
    """The person's hands for one run: `run(done)` until `done` is set."""

    def __init__(self, url: str, run_id: int, seen: Path, *, seed: int, control_hz: float, demos: int = 0) -> None:
        self.url, self.run_id, self.seen = url, run_id, seen
        self.rng = np.random.default_rng([seed, 57])
        self.half_period = 0.5 / control_hz
        self.demos = demos
        self.demos_asked = False  # Record demos accepted
        self.demos_driven = 0  # demo episodes driven (found waiting for the keys)
        self.episodes_helped = 0
        self.actions_sent = 0

    def _helps_in(self, episode: int) -> tuple[bool, int]:
        """Whether the person drives in `episode` (a new one), and after how many of the policy's steps."""
        if self.demos:  # (a demo episode is driven once the robot waits for the keys: see `run`)
            return False, 0
        asked = asks_for_help(self.url, self.run_id)
        return bool(self.rng.random() < help_chance(episode, asked)), int(self.rng.integers(0, LATEST_START_STEPS + 1))

    def run(self, done: threading.Event) -> None:
        episode, helping, start_after, driving = 0, False, 0, False
        drive = f"{self.url}/api/runs/{self.run_id}/robot/drive"
        while not done.is_set():
            state = seen_state(self.seen)
            if self.demos and not self.demos_asked and state is not None:  # (409 until the actor has reported)
                with contextlib.suppress(OSError):
                    self.demos_asked = (
                        post(f"{self.url}/api/runs/{self.run_id}/robot/demos", {"episodes": self.demos}) == 202
                    )
            if state is not None and state["episode"] != episode:  # a new episode: help in it or not
                episode = state["episode"]
                helping, start_after = self._helps_in(episode)
                self.episodes_helped += helping
            if self.demos_asked and self.demos_driven < self.demos and not helping and state is not None:
                helping = waits_for_keys(self.url, self.run_id) and not state["success"]  # (a demo: from its start)
                self.episodes_helped += helping
                self.demos_driven += helping
            wanted = helping and state is not None and state["step"] >= start_after and not state["success"]
            if wanted:
                try:
                    code = post(drive, {"action": [round(float(v), 4) for v in expert_action(state)]})
                except OSError:
                    code = 0
                driving = code == 202
                self.actions_sent += driving
            elif driving:
                with contextlib.suppress(OSError):
                    post(f"{self.url}/api/runs/{self.run_id}/robot/hand-back")
                driving = False
            if state is not None and state["success"] and helping:
                helping = False  # (the mug is on the coaster: the policy has the rest of the episode)
                if self.demos:  # the success key: the demo's last frames are positives, and the demo ends
                    with contextlib.suppress(OSError):
                        post(f"{self.url}/api/runs/{self.run_id}/robot/success")
            done.wait(self.half_period)
