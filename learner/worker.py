"""`raq learn`: claim runs from the store and train them, one at a time.

SIGTERM / Ctrl-C: the run in progress is checkpointed and put back to "queued", so it resumes from there when
a learner starts again. A learner killed outright (SIGKILL, power loss) stops beating; after
stale_heartbeat_seconds another learner reclaims the run and resumes it from its last checkpoint.

    python -m learner.worker [--once] [--name NAME] [--poll SECONDS]
"""

import argparse
import contextlib
import logging
import os
import signal
import socket
import threading
import traceback
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

from contract.settings import Settings, get_settings
from contract.store import NotFound, RunStatus, Store
from learner.train import Outcome, train_run

logger = logging.getLogger(__name__)


@contextmanager
def _interrupt_on_signals(interrupt: threading.Event) -> Iterator[None]:
    """SIGTERM and SIGINT set `interrupt` (only possible from the main thread; elsewhere nothing changes)."""
    previous: dict[int, object] = {}

    def handler(signum: int, _frame: FrameType | None) -> None:
        interrupt.set()

    try:
        for signum in (signal.SIGTERM, signal.SIGINT):
            previous[signum] = signal.signal(signum, handler)
    except ValueError:  # not the main thread
        pass
    try:
        yield
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old)  # type: ignore[arg-type]


# SQLAlchemy ends its messages with "[SQL: …]", "[parameters: …]" and "(Background on this error at: …)" lines.
_FOOTER_PREFIXES = ("(Background on this error at:", "[SQL:", "[parameters:")


def _last_line(error: BaseException) -> str:
    """The error's type and message as one line: its last line, skipping SQLAlchemy's footer lines."""
    lines = [line for line in "".join(traceback.format_exception_only(error)).strip().splitlines() if line.strip()]
    lines = [line for line in lines if not line.strip().startswith(_FOOTER_PREFIXES)] or lines
    return lines[-1] if lines else type(error).__name__


def work(
    settings: Settings,
    *,
    worker_name: str | None = None,
    once: bool = False,
    poll_seconds: float = 2.0,
    interrupt: threading.Event | None = None,
) -> int:
    """Claim and train runs until interrupted; with once=True, at most one run. Returns an exit code:
    0, or 1 when (with once=True) the run failed."""
    worker = worker_name or f"{socket.gethostname()}-{os.getpid()}"
    interrupt = interrupt or threading.Event()
    store = Store(settings.resolved_database_url)
    try:
        with _interrupt_on_signals(interrupt):
            while not interrupt.is_set():
                run = store.claim_next_run(worker=worker, stale_after_seconds=settings.stale_heartbeat_seconds)
                if run is None:
                    if once:
                        return 0
                    interrupt.wait(poll_seconds)
                    continue
                logger.info("%s claimed run %s (%s on %s)", worker, run.id, run.algorithm, run.env_id)
                failed = _train_one(store, run.id, settings, worker, interrupt)
                if once or interrupt.is_set():
                    return 1 if failed else 0
            return 0
    finally:
        store.dispose()


def _train_one(store: Store, run_id: int, settings: Settings, worker: str, interrupt: threading.Event) -> bool:
    """Train one claimed run; a failure marks it failed with the error's last line. Returns True if it failed."""
    try:
        run = store.get_run(run_id=run_id)
        outcome = train_run(
            store, run, checkpoint_url=settings.resolved_checkpoint_url, worker=worker, interrupt=interrupt
        )
    except Exception as error:
        reason = _last_line(error)
        logger.exception("run %s failed: %s", run_id, reason)
        store.record_event(run_id=run_id, level="error", message="".join(traceback.format_exception(error))[-4000:])
        with contextlib.suppress(NotFound):  # the run was taken from this worker meanwhile
            store.set_run_status(run_id=run_id, status=RunStatus.FAILED, reason=reason, worker=worker)
        return True
    logger.info("run %s: %s", run_id, outcome)
    return outcome not in (Outcome.FINISHED, Outcome.STOPPED, Outcome.REQUEUED, Outcome.LOST)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Claim queued runs from the store and train them.")
    parser.add_argument("--once", action="store_true", help="train at most one run, then exit")
    parser.add_argument("--name", default=None, help="worker name shown in the UI (default host-pid)")
    parser.add_argument("--poll", type=float, default=2.0, help="seconds between looks for a queued run")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    return work(get_settings(), worker_name=args.name, once=args.once, poll_seconds=args.poll)


if __name__ == "__main__":
    raise SystemExit(main())
