"""Run control of one claimed run: its checkpointed counters, heartbeats, stop requests, interrupts, events.

The learner holds a run only while its heartbeats are accepted. A refused heartbeat (the run was stopped, or
taken over by another learner after this one went silent) is noticed at the next env step; an interrupt (Ctrl-C,
SIGTERM) checkpoints and queues the run again so the next learner resumes it there.
"""

import logging
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from typing import Any

from contract.store import RunStatus, Store


def cuda_devices() -> int:
    """The CUDA GPUs this learner can use (torch's count, under CUDA_VISIBLE_DEVICES): a learner claims only runs
    whose device it has (Store.claim_next_run)."""
    import torch  # noqa: PLC0415 - the learner's own dependency, not the contract's

    return torch.cuda.device_count() if torch.cuda.is_available() else 0


logger = logging.getLogger("learner.train")


class Outcome:
    """How training a claimed run ended."""

    FINISHED = "finished"
    STOPPED = "stopped"
    REQUEUED = "requeued"
    LOST = "lost"


@dataclass
class Counters:
    """The loop's counters that a checkpoint keeps (its keys are the checkpoint's)."""

    step: int = 0
    """Env steps taken."""
    total_updates: int = 0
    """SAC updates done."""
    answer_cursor: int = 0
    """The answer sequence number read up to: answers after it are new."""
    naive_trained: bool = False
    """The naive classifier's one-off training is done (it is frozen from then on)."""
    evaluated_step: int = -1
    """The step of the last completed evaluation."""
    actor_message: int = 0
    """The id of the remote actor's last message taken: the checkpoint holds every step up to it, the store the
    actor's later ones."""

    def state_dict(self) -> dict[str, Any]:
        return asdict(self)

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.step, self.total_updates = int(state["step"]), int(state["total_updates"])
        self.answer_cursor, self.naive_trained = int(state["answer_cursor"]), bool(state["naive_trained"])
        self.evaluated_step = int(state.get("evaluated_step", self.step))
        self.actor_message = int(state.get("actor_message", 0))


class RunControl:
    """Heartbeats, stop and interrupt checks and progress events for one run held by `worker`."""

    def __init__(
        self, store: Store, *, run_id: int, worker: str, counters: Counters, heartbeat_seconds: float,
        interrupt: threading.Event,
    ) -> None:  # fmt: skip
        self.store, self.run_id, self.worker = store, run_id, worker
        self.counters, self.heartbeat_seconds, self.interrupt = counters, heartbeat_seconds, interrupt
        self.step_known = False  # until the checkpoint is read, heartbeats leave the run's stored step alone
        self.last_beat = 0.0
        self.beat_refused = False
        self.yield_to: Any = None  # a higher-priority queued run found at the last checkpoint
        self.phase: str | None = None  # RunPhase, sent with every heartbeat
        self.beat_lock = threading.Lock()
        self.beating = threading.Event()  # set while the heartbeat thread runs

    def set_phase(self, phase: str) -> None:
        """Say what the learner is doing now (warm-up, training, evaluating): one heartbeat when it changes."""
        if phase != self.phase:
            self.phase = phase
            if not self.beat():
                self.beat_refused = True

    def look_for_higher_priority(self) -> None:
        """At a checkpoint: note a higher-priority run waiting for a learner; the loop then yields to it."""
        self.yield_to = self.store.higher_priority_waiting(run_id=self.run_id, cuda_devices=cuda_devices())

    @property
    def interrupted(self) -> bool:
        return self.interrupt.is_set()

    def beat(self, status: str | None = None) -> bool:
        """Send a heartbeat (with the step, once known); False when the store refuses it."""
        with self.beat_lock:
            self.last_beat = time.monotonic()
            step = self.counters.step if self.step_known else None
            return self.store.heartbeat(
                run_id=self.run_id, worker=self.worker, step=step, status=status, phase=self.phase
            )

    @contextmanager
    def heartbeats(self) -> Iterator[None]:
        """Heartbeats every heartbeat_seconds from a thread of their own while training runs: a long classifier
        epoch, a slow checkpoint or a busy host cannot silence a live learner long enough for another to take its
        run (and its robot). A refusal is acted on at the next env step, as `tick`'s."""
        self.beating.set()
        thread = threading.Thread(target=self._beat_on, name=f"heartbeat-run-{self.run_id}", daemon=True)
        thread.start()
        try:
            yield
        finally:
            self.beating.clear()
            thread.join(timeout=self.heartbeat_seconds + 1.0)

    def _beat_on(self) -> None:
        while self.beating.is_set():
            wait = self.last_beat + self.heartbeat_seconds - time.monotonic()
            if wait > 0:
                time.sleep(min(wait, 0.1))  # (short sleeps: the thread ends soon after training does)
                continue
            try:
                if not self.beat():
                    self.beat_refused = True
            except Exception as error:  # noqa: BLE001 - the loop's own store calls meet (and report) the same error
                logger.warning("run %s: heartbeat failed: %s", self.run_id, error)
                time.sleep(self.heartbeat_seconds)

    def tick(self) -> None:
        """Heartbeat when one is due (also inside long steps); a refusal is acted on at the next env step."""
        if time.monotonic() - self.last_beat >= self.heartbeat_seconds and not self.beat():
            self.beat_refused = True

    def take_refusal(self) -> bool:
        """Whether a heartbeat was refused since the last call."""
        refused, self.beat_refused = self.beat_refused, False
        return refused

    def requeue(self) -> str:
        """After an interrupt (the caller checkpointed): queue the run again at this step."""
        self.beat()  # the run shows the step it will resume at
        self.store.set_run_status(
            run_id=self.run_id, status=RunStatus.QUEUED, reason="learner interrupted", worker=self.worker
        )
        self.event(f"learner {self.worker} interrupted at step {self.counters.step}: run queued again, it resumes here")
        return Outcome.REQUEUED

    def holds_run(self) -> bool:
        """The run is still this worker's (a learner that stalled past the staleness limit may have lost it)."""
        run = self.store.get_run(run_id=self.run_id)
        return run.worker == self.worker and run.status in RunStatus.ACTIVE

    def yielded(self) -> str:
        """After a checkpoint found a higher-priority run waiting: queue this run again so a learner takes that one
        first; this run resumes from the checkpoint when a learner is free."""
        other = self.yield_to
        self.yield_to = None
        self.beat()
        reason = f"yielded to run #{other.id} (priority {other.priority})"
        self.store.set_run_status(run_id=self.run_id, status=RunStatus.QUEUED, reason=reason, worker=self.worker)
        self.event(f"{reason} at step {self.counters.step}: queued again, it resumes from this checkpoint")
        return Outcome.REQUEUED

    def still_held_and_stopping(self) -> bool:
        """The run is still this worker's and a person asked it to stop (else it was taken from this worker)."""
        run = self.store.get_run(run_id=self.run_id)
        return run.worker == self.worker and run.status in RunStatus.ACTIVE and bool(run.stop_requested)

    def stopped(self) -> str:
        """After a stop request (the caller checkpointed): mark the run stopped."""
        self.beat()
        self.store.set_run_status(run_id=self.run_id, status=RunStatus.STOPPED, worker=self.worker)
        return Outcome.STOPPED

    def lost(self) -> str:
        run = self.store.get_run(run_id=self.run_id)
        self.event(f"learner {self.worker} no longer holds the run (now {run.status}, {run.worker}); leaving it")
        return Outcome.LOST

    def finished(self) -> str:
        self.beat()
        self.store.set_run_status(run_id=self.run_id, status=RunStatus.FINISHED, worker=self.worker)
        return Outcome.FINISHED

    def event(self, message: str, level: str = "info") -> None:
        """A progress message for the UI (the run's events) and the learner's console."""
        levels = {"error": logging.ERROR, "warning": logging.WARNING}
        logger.log(levels.get(level, logging.INFO), "run %s: %s", self.run_id, message)
        self.store.record_event(run_id=self.run_id, message=message, level=level)
