"""The store as a learner uses it: every call waits out a database that is briefly away.

A restarted PostgreSQL, a failover or a full disk makes calls raise for a while (`contract.store.is_transient`);
each is retried with backoff (0.5 s, doubling to 10 s) until it succeeds or `patience` seconds have passed, so a
learner neither dies nor fails its run because the database blinked. Any other error is raised at once. A write
whose commit reached the database just before the connection dropped may be applied twice (one more metric row or
event); answers are the server's writes, never the learner's, so none of them is ever duplicated or lost.
"""

import functools
import logging
import time
from collections.abc import Callable
from typing import Any, cast

from contract.store import Store, first_line, is_transient

logger = logging.getLogger(__name__)

FIRST_PAUSE_S = 0.5
LONGEST_PAUSE_S = 10.0


class PatientStore:
    """Wraps a Store; its methods are the store's, retried while the database is briefly away."""

    def __init__(self, store: Store, *, patience: float) -> None:
        self.store, self.patience = store, patience

    def __getattr__(self, name: str) -> Any:
        value = getattr(self.store, name)
        if name.startswith("_") or not callable(value):
            return value

        @functools.wraps(value)
        def patient(*args: Any, **kwargs: Any) -> Any:
            return self.call(value, *args, **kwargs)

        return patient

    def call(self, method: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        deadline = time.monotonic() + self.patience
        pause, failures = FIRST_PAUSE_S, 0
        while True:
            try:
                result = method(*args, **kwargs)
            except Exception as error:
                if not is_transient(error) or time.monotonic() + pause > deadline:
                    raise
                if failures == 0:
                    logger.warning("the database is away (%s): retrying %s", first_line(error), method.__name__)
                failures += 1
                time.sleep(pause)
                pause = min(2 * pause, LONGEST_PAUSE_S)
                continue
            if failures:
                logger.info("the database is back after %d retries of %s", failures, method.__name__)
            return result


def patient(store: Store, *, patience: float) -> Store:
    """`store` with every call retried while the database is briefly away (typed as the Store it stands for)."""
    return cast(Store, PatientStore(store, patience=patience))
