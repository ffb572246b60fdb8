"""`raq up --demo` on an empty database: a simulated pusher goal set and one queued VICE-RAQ run, once."""

from pathlib import Path

from app.demo import DEMO_GOAL_COUNT, ensure_demo_run
from contract.config import TrainConfig
from contract.settings import Settings
from contract.store import Store


def test_demo_run_is_made_once_on_an_empty_database(tmp_path: Path, database_url: str) -> None:
    settings = Settings(data_dir=tmp_path, database_url=database_url)
    run_id = ensure_demo_run(settings)
    assert run_id is not None
    assert ensure_demo_run(settings) is None  # there are runs now: nothing more is made
    store = Store(database_url)
    run = store.get_run(run_id=run_id)
    config = TrainConfig.from_dict(run.config)
    assert (run.status, run.env_id, run.algorithm) == ("queued", "VisualPusher-v0", "vice_raq")
    assert config.query_every <= 1000  # the first query shows up within minutes
    examples = store.list_goal_examples(goal_set_id=run.goal_set_id)
    assert len(examples) == DEMO_GOAL_COUNT
    assert all(example.source == "simulation" for example in examples)
    pngs = {store.goal_example_image(example_id=example.id, kind="model") for example in examples}
    assert len(pngs) == DEMO_GOAL_COUNT  # varied goal images, none repeated
    store.dispose()
