"""The paper's three simulated tasks as Gymnasium environments: pixels in, end-effector displacements out.

`import sim` registers `VisualPusher-v0`, `VisualDoor-v0` and `VisualPicker-v0` (100-step episodes).
This package imports no torch and no database code.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium

TASKS: dict[str, str] = {
    "pusher": "VisualPusher-v0",
    "door": "VisualDoor-v0",
    "picker": "VisualPicker-v0",
}

_ENTRY_POINTS: dict[str, str] = {
    "VisualPusher-v0": "sim.pusher:VisualPusherEnv",
    "VisualDoor-v0": "sim.door:VisualDoorEnv",
    "VisualPicker-v0": "sim.picker:VisualPickerEnv",
}

MAX_EPISODE_STEPS = 100

for _env_id, _entry_point in _ENTRY_POINTS.items():
    if _env_id not in gymnasium.registry:
        gymnasium.register(id=_env_id, entry_point=_entry_point, max_episode_steps=MAX_EPISODE_STEPS)

__all__ = ["MAX_EPISODE_STEPS", "TASKS"]
