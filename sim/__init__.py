"""The paper's three simulated tasks as Gymnasium environments: pixels in, end-effector displacements out.

`import sim` registers `VisualPusher-v0`, `VisualDoor-v0`, `VisualPicker-v0`, `VisualBookshelf-v0` and
`VisualDraping-v0` (100-step episodes).
This package imports no torch and no database code.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium

TASKS: dict[str, str] = {
    "pusher": "VisualPusher-v0",
    "door": "VisualDoor-v0",
    "picker": "VisualPicker-v0",
    "bookshelf": "VisualBookshelf-v0",
    "draping": "VisualDraping-v0",
}

_ENTRY_POINTS: dict[str, str] = {
    "VisualPusher-v0": "sim.pusher:VisualPusherEnv",
    "VisualDoor-v0": "sim.door:VisualDoorEnv",
    "VisualPicker-v0": "sim.picker:VisualPickerEnv",
    "VisualBookshelf-v0": "sim.bookshelf:VisualBookshelfEnv",
    "VisualDraping-v0": "sim.draping:VisualDrapingEnv",
}

MAX_EPISODE_STEPS = 100

PRESET_FIELDS = ("query_every", "query_budget", "episode_steps")
"""What a task preset may set: what the paper also set per task, the queries' interval and budget and the episode
length. Everything else is one default for every task."""

PRESETS: dict[str, dict[str, int]] = {
    "VisualPusher-v0": {"query_every": 5000, "query_budget": 20},
    "VisualDoor-v0": {"query_every": 1000, "query_budget": 50},
    "VisualPicker-v0": {"query_every": 1000, "query_budget": 50},
    "VisualBookshelf-v0": {"query_every": 750, "query_budget": 20},
    "VisualDraping-v0": {"query_every": 750, "query_budget": 20},
}
"""Per task, the training-config fields (of PRESET_FIELDS) a run of it starts from (every other field: its
default); how well each learns with them is in docs/results.md."""

for _env_id, _entry_point in _ENTRY_POINTS.items():
    if _env_id not in gymnasium.registry:
        gymnasium.register(id=_env_id, entry_point=_entry_point, max_episode_steps=MAX_EPISODE_STEPS)

__all__ = ["MAX_EPISODE_STEPS", "PRESET_FIELDS", "PRESETS", "TASKS"]
