"""A store whose every call answers within a bounded time, for the code that moves a robot: a database link that
goes silent (a pulled cable, a proxy that stops forwarding) leaves a call waiting for minutes, and a thread that
waits there can neither hold the arm nor notice that it should. Each call runs on a worker thread; the caller waits
`seconds` at most and then gets StoreSilent, as if the store were away. A late answer (a "you hold the robot" that
arrives after the link heals) goes to nobody.
"""

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any

from contract.store.errors import StoreSilent
from contract.store.store import Store

BOUNDED_WORKERS = 8
"""Worker threads: calls stuck on a silent link hold one each, and later calls queue (and time out) behind them."""


class BoundedStore:
    """`store`'s methods, each answering within `seconds` or raising StoreSilent."""

    def __init__(self, store: Store, *, seconds: float) -> None:
        self.store, self.seconds = store, float(seconds)
        self.pool = ThreadPoolExecutor(max_workers=BOUNDED_WORKERS, thread_name_prefix="store-call")

    def __getattr__(self, name: str) -> Any:
        attribute = getattr(self.store, name)
        if not callable(attribute):
            return attribute
        return self._bounded(attribute)

    def _bounded(self, call: Callable[..., Any]) -> Callable[..., Any]:
        def bounded(*args: Any, **kwargs: Any) -> Any:
            future = self.pool.submit(call, *args, **kwargs)
            try:
                return future.result(timeout=self.seconds)
            except FutureTimeout:
                future.cancel()  # (one still queued never runs)
                raise StoreSilent(f"{call.__name__}: no answer from the store within {self.seconds:g} s") from None

        return bounded

    def close(self) -> None:
        """Stop the workers without waiting for calls stuck on a silent link."""
        self.pool.shutdown(wait=False, cancel_futures=True)
