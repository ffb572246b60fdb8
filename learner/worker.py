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

from contract.envs import BadObservation
from contract.settings import Settings, get_settings
from contract.store import NotFound, RunStatus, Store, first_line, is_transient
from learner.checkpoint import CheckpointStoreFull
from learner.patient_store import LONGEST_PAUSE_S, patient
from learner.run_control import cuda_devices
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
    gpus = cuda_devices()  # it claims only runs it can execute: a run on "cuda" waits for a learner with a GPU
    store = patient(Store(settings.resolved_database_url), patience=settings.database_patience_seconds)
    try:
        with _interrupt_on_signals(interrupt):
            while not interrupt.is_set():
                try:
                    run = store.claim_next_run(
                        worker=worker, stale_after_seconds=settings.stale_heartbeat_seconds, cuda_devices=gpus
                    )
                except Exception as error:
                    if not is_transient(error):
                        raise
                    logger.warning("the database is still away (%s); looking again", first_line(error))
                    interrupt.wait(poll_seconds)
                    continue
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
    """Train one claimed run; a failure marks it failed with the error's first line. A database away for longer
    than the store's patience is not a failure: the run goes back to the queue. Anything else is: a full checkpoint
    store, an env's own error (a connection reset included). Returns True if it failed."""
    try:
        run = store.get_run(run_id=run_id)
        outcome = train_run(
            store, run, checkpoint_url=settings.resolved_checkpoint_url, worker=worker, interrupt=interrupt
        )
    except Exception as error:
        if is_transient(error):
            logger.warning("run %s: the database stayed away (%s); the run goes back to the queue", run_id,
                           first_line(error))  # fmt: skip
            _give_back(store, run_id, worker, interrupt)
            return False
        # "<env id>: <problem>", "checkpoint store full: …", else "<error type>: <first line of its message>"
        reason = str(error) if isinstance(error, BadObservation | CheckpointStoreFull) else first_line(error)
        logger.exception("run %s failed: %s", run_id, reason)
        try:
            store.record_event(run_id=run_id, level="error", message="".join(traceback.format_exception(error))[-4000:])
            with contextlib.suppress(NotFound):  # the run was taken from this worker meanwhile
                store.set_run_status(run_id=run_id, status=RunStatus.FAILED, reason=reason, worker=worker)
        except Exception as report_error:  # the database went away as well: the run is reclaimed when it is back
            if not is_transient(report_error):
                raise
            logger.warning("run %s: could not record the failure (%s)", run_id, first_line(report_error))
        return True
    logger.info("run %s: %s", run_id, outcome)
    return outcome not in (Outcome.FINISHED, Outcome.STOPPED, Outcome.REQUEUED, Outcome.LOST)


def _give_back(store: Store, run_id: int, worker: str, interrupt: threading.Event) -> None:
    """Queue the run again once the database answers (it resumes from its last checkpoint); until then, wait."""
    while not interrupt.is_set():
        try:
            with contextlib.suppress(NotFound):  # another learner reclaimed it meanwhile
                store.set_run_status(run_id=run_id, status=RunStatus.QUEUED, reason="", worker=worker)
            return
        except Exception as error:
            if not is_transient(error):
                raise
            interrupt.wait(LONGEST_PAUSE_S)


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
