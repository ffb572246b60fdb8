"""A run fails once, saying why, when something other than the database breaks: a full checkpoint store and an env
that loses its own connection are the run's failure (one line naming it), never "the database blinked" and
never a requeue that comes back every few seconds. Only the database's own connection errors are a blink."""

import errno
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import sqlalchemy as sa
from conftest import mounted_tmpfs
from test_learner_run import create_run, tiny_config

from app.migrate import upgrade
from contract.settings import Settings
from contract.store import RunStatus, Store, is_transient
from learner.testing_envs import DotReach
from learner.worker import work


class ResetByPeerDot(DotReach):
    """DotReach whose link to its (pretend) hardware drops at the fifth step: ConnectionResetError, errno 104."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.steps = 0

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        self.steps += 1
        if self.steps == 5:
            raise ConnectionResetError(errno.ECONNRESET, "Connection reset by peer (the arm's controller)")
        return super().step(action)


RESET_BY_PEER = "ResetByPeerDot-v0"
if RESET_BY_PEER not in gym.registry:
    gym.register(id=RESET_BY_PEER, entry_point=ResetByPeerDot, max_episode_steps=50)


@pytest.fixture
def store(tmp_path: Path) -> Iterator[Store]:
    url = f"sqlite:///{tmp_path / 'raq.sqlite3'}"
    upgrade(url)
    opened = Store(url)
    yield opened
    opened.dispose()


def test_only_the_databases_connection_errors_are_a_blink(tmp_path: Path) -> None:
    """A dropped or refused database connection is transient; the same errno from anything else is not."""
    engine = sa.create_engine("postgresql+psycopg://raq@127.0.0.1:1/raq", connect_args={"connect_timeout": 2})
    with pytest.raises(sa.exc.OperationalError) as refused:
        engine.connect()
    engine.dispose()
    assert is_transient(refused.value)
    assert not is_transient(ConnectionResetError(errno.ECONNRESET, "Connection reset by peer"))
    assert not is_transient(ConnectionRefusedError(errno.ECONNREFUSED, "Connection refused"))
    assert not is_transient(OSError(errno.ENOSPC, "No space left on device"))


def test_an_env_that_loses_its_connection_fails_its_run_in_one_line(store: Store, tmp_path: Path) -> None:
    settings = Settings(_env_file=None, data_dir=tmp_path, database_url=str(store.engine.url))
    run_id = create_run(store, None, tiny_config(env_id=RESET_BY_PEER, algorithm="sparse"))
    assert work(settings, worker_name="w", once=True) == 1
    run = store.get_run(run_id=run_id)
    assert run.status == RunStatus.FAILED, (run.status, run.status_reason)
    assert run.status_reason.startswith("ConnectionResetError: [Errno 104] Connection reset by peer"), run.status_reason
    assert "\n" not in run.status_reason


@pytest.fixture
def full_disk(tmp_path: Path) -> Iterator[Path]:
    """A 128 KiB tmpfs of this test's own: too small for a checkpoint."""
    with mounted_tmpfs(tmp_path / "checkpoints", "128k") as mount:
        yield mount


def test_a_full_checkpoint_store_fails_the_run_once_saying_so(store: Store, tmp_path: Path, full_disk: Path) -> None:
    settings = Settings(
        _env_file=None, data_dir=tmp_path, database_url=str(store.engine.url), checkpoint_url=str(full_disk)
    )
    run_id = create_run(store, None, tiny_config(algorithm="sparse"))
    assert work(settings, worker_name="w", once=True) == 1  # failed, not given back to the queue
    run = store.get_run(run_id=run_id)
    assert run.status == RunStatus.FAILED, (run.status, run.status_reason)
    assert run.status_reason.startswith("checkpoint store full: "), run.status_reason
    assert "No space left on device" in run.status_reason and "\n" not in run.status_reason
    assert work(settings, worker_name="w", once=True) == 0  # nothing queued again
    assert not [path.name for path in full_disk.rglob("*.tmp-*")]  # no half-written file left behind
