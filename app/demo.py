"""Something to see on a fresh install: a pusher goal set made in simulation and a VICE-RAQ run."""

import io
import logging

import numpy as np
from PIL import Image

from contract.config import TrainConfig
from contract.settings import Settings
from contract.store import Store

logger = logging.getLogger(__name__)

DEMO_GOAL_SET = "pusher goals (simulated)"
DEMO_GOAL_COUNT = 10
DEMO_STEPS = 25_000
DEMO_PRIORITY = -10


def png_bytes(pixels: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="PNG")
    return buffer.getvalue()


def add_simulated_goal_set(store: Store, *, task: str, name: str, count: int, image_size: int = 48) -> int:
    """Render `count` goal examples of a simulated task into a new goal set; returns its id."""
    from sim import TASKS
    from sim.goals import make_goal_examples

    goal_set = store.create_goal_set(name=name, image_size=image_size, env_id=TASKS.get(task))
    for index, example in enumerate(make_goal_examples(task, count, seed=0, image_size=image_size)):
        display = png_bytes(example.display)
        store.add_goal_example(
            goal_set_id=goal_set.id,
            filename=f"{task}-goal-{index:02d}.png",
            original=display,
            original_media_type="image/png",
            width=int(example.display.shape[1]),
            height=int(example.display.shape[0]),
            model_png=png_bytes(example.image),
            display_png=display,
            source="simulation",
        )
    return goal_set.id


def ensure_demo_run(settings: Settings) -> int | None:
    """When the database has no runs, start a VICE-RAQ pusher run that asks its first query within minutes."""
    store = Store(settings.resolved_database_url)
    try:
        if store.count_runs():
            return None
        existing = store.find_goal_set(name=DEMO_GOAL_SET)
        goal_set_id = (
            existing.id
            if existing
            else add_simulated_goal_set(store, task="pusher", name=DEMO_GOAL_SET, count=DEMO_GOAL_COUNT)
        )
        # Short enough to finish and show learning (the pusher reaches 90% within about 20K steps), and behind any
        # run a person starts (priority -10): it yields to theirs at its next checkpoint (every 5,000 steps).
        config = TrainConfig(
            env_id="VisualPusher-v0", algorithm="vice_raq", query_every=1000, query_budget=30,
            total_steps=DEMO_STEPS, checkpoint_every=5000,
        )  # fmt: skip
        run = store.create_run(
            name="demo: push the mug onto the coaster",
            env_id=config.env_id,
            algorithm=config.algorithm,
            config=config.to_dict(),
            seed=config.seed,
            goal_set_id=goal_set_id,
            total_steps=config.total_steps,
            priority=DEMO_PRIORITY,
        )
        print(
            f"demo: queued run {run.id} (VICE-RAQ on VisualPusher-v0, {DEMO_STEPS} steps, a query every 1000 steps, "
            f"priority {DEMO_PRIORITY})",
            flush=True,
        )
        return run.id
    finally:
        store.dispose()
