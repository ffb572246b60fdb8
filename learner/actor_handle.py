"""The learner's end of its link with a real-time actor, through the database and the checkpoint store (a folder
both mount, or object storage by URL); the actor's end is robot/drive/link.py, the wire contract/actor_messages.py.

A robot's actor is its own process's (`raq robot ENV`, robot/drive/process.py): the learner links to it
(`RemoteActor`) and never drives the robot itself. A paced simulated env's actor runs beside its learner
(`ActorProcess`, a child process running `serve_child`), linked the same way, so that every step is stored as it
happens.

`RemoteActor` opens the link, stamps a keep-alive four times a second, writes each new pi to the checkpoint store
(ACTOR_POLICY_FILENAME) and publishes its version, and takes the actor's steps from the database in order; they
stay there until a checkpoint holds them, so the learner that takes a run over first takes those its checkpoint
does not hold (`resume`). The watchdog is the actor's: no keep-alive for `watchdog_seconds` (the learner died, or
its host is cut off) or no answer from the database that long, and the arm is held safe.
"""

import contextlib
import multiprocessing
import os
import threading
import time
import traceback
from collections import deque
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from contract.actor_messages import (
    LINK_POLL_SECONDS,
    ActorError,
    ActorMessage,
    EpisodeStart,
    Failure,
    Transition,
    decode_message,
    driven_run,
    raised,
    spaces_of,
)
from contract.checkpoint_location import ACTOR_POLICY_FILENAME, sibling
from contract.store import Store, is_transient
from learner.acting import SAC_ACTING
from learner.checkpoint import save_checkpoint
from robot.drive.actor import ActorLoop, ActorSettings
from robot.drive.link import StoreLink

KEEPALIVE_SECONDS = 0.25
"""How often the learner tells the actor it is alive (from a thread of its own: long updates do not delay it)."""
START_SECONDS = 120.0
"""How long an actor beside its learner may take to import its modules and make its env."""
ACTOR_WAIT_SECONDS = 600.0
"""How long a learner waits for the robot's process (`raq robot ENV`) to take its run before the run fails."""
ACTOR_LIVE_SECONDS = 5.0
"""An actor that reported within this many seconds is up."""


def waiting_for_robot(env_id: str) -> str:
    """What a run of a robot says while no process of its robot is up."""
    return (
        f"waiting for the robot's own process: start `raq robot {env_id}` on the robot's host (`raq up` starts it "
        "on its own host)"
    )


def serve_child(settings: ActorSettings, policy_url: str, parent_pid: int, started: Connection) -> None:
    """A paced simulated env's actor beside its learner, in a process of its own: step the env for that learner until
    it closes the link or its process is gone, then end. `started` gets None once the actor is announced, or
    the traceback of why it could not start; a failure after that goes to the learner through the link.

    The process ends with os._exit once the link's last messages are posted: nothing it started may keep it alive."""
    code = 0
    link = StoreLink(
        Store(settings.database_url), run_id=settings.run_id, policy_url=policy_url, hz=settings.control_hz,
        read_weights=SAC_ACTING.read_weights, parent_pid=parent_pid, announced=lambda: started.send(None),
    )  # fmt: skip
    try:
        actor = ActorLoop(settings, link.connection, link.outbox, SAC_ACTING)
    except Exception:
        with contextlib.suppress(Exception):
            started.send(traceback.format_exc())
        os._exit(1)
    try:
        actor.run()
    except Exception:
        link.outbox.put(Failure(traceback.format_exc()))
        code = 1
    finally:
        link.close()
        with contextlib.suppress(Exception):
            started.close()
        os._exit(code)


# ====================================================================== the learner's end
class RemoteActor:
    """The learner's handle on an actor on another host, with the interface of the actor beside it."""

    def __init__(self, store: Store, *, run_id: int, claim: int, checkpoint_file: str, heartbeat: Any = None) -> None:
        """Open the link for the run's `claim` (this learner's: every write to the link carries it, and is skipped
        once the run is claimed again) and wait (`heartbeat()` called meanwhile) for the actor to announce itself."""
        self.store, self.run_id, self.claim = store, run_id, claim
        self.policy_url = sibling(checkpoint_file, ACTOR_POLICY_FILENAME)
        self.closed = threading.Event()
        self.display: np.ndarray | None = None
        self.buffer: deque[tuple[int, Any]] = deque()  # (id, message)
        self.cursor, self.fetched_at = 0, -1.0  # (the id of the last message fetched)
        self.taken = 0
        """The id of the last message next_message returned."""
        self.policy_version = store.open_actor_link(run_id=run_id, claim=claim, start_step=None).policy_version
        self.keepalive = threading.Thread(target=self._keep_alive, name="link-keepalive", daemon=True)
        self.keepalive.start()
        try:
            self._wait_for_actor(heartbeat)
        except BaseException:
            self.close()
            raise
        announced = store.actor_link(run_id=run_id).actor_spaces
        self.action_space, self.observation_space = spaces_of(announced)
        self.control_hz = float(announced["control_hz"])

    def _wait_for_actor(self, heartbeat: Any) -> None:
        """Until the robot's process has announced itself for this run and reported lately (ActorError after
        ACTOR_WAIT_SECONDS without one, not counting the time the robot's process drives another run: the run's
        events say which)."""
        deadline = time.monotonic() + ACTOR_WAIT_SECONDS
        env_id, busy_with, told = self.store.get_run(run_id=self.run_id).env_id, None, False
        while True:
            link = self.store.actor_link(run_id=self.run_id)
            alive = link.actor_age_seconds is not None and link.actor_age_seconds < ACTOR_LIVE_SECONDS
            if link.actor_spaces is not None and alive:
                return
            robot = self.store.robot_process_of(env_id=env_id)
            if robot is None and not told:  # (said once: the run's page shows it)
                told = True
                self.store.record_event(run_id=self.run_id, message=waiting_for_robot(env_id))
            other = None if robot is None else driven_run(robot.state)
            if robot is not None and other not in (None, self.run_id):  # the robot is up, and busy
                deadline = time.monotonic() + ACTOR_WAIT_SECONDS
                if other != busy_with:
                    busy_with = other
                    self.store.record_event(run_id=self.run_id, message=f"waiting for {robot.robot}: {robot.state}")
            if time.monotonic() > deadline:
                raise ActorError(
                    f"no actor for run {self.run_id} within {ACTOR_WAIT_SECONDS:.0f} s: start `raq robot ENV_ID` (or "
                    f"`raq actor --run {self.run_id}`) on the robot's host"
                )
            if heartbeat is not None:
                heartbeat()
            time.sleep(LINK_POLL_SECONDS * 4)

    @property
    def unwrapped(self) -> "RemoteActor":
        return self

    def render(self) -> np.ndarray | None:
        """The display frame sent with the last message (the state of the newest observation)."""
        return self.display

    def start(self, step: int, claim: int) -> None:
        """The run is at `step` (after its checkpoint): the actor may begin its first episode (it reads the run's
        claim when it sees the start: the one this learner holds)."""
        self.store.start_actor_link(run_id=self.run_id, claim=self.claim, start_step=step)

    def resume(self, taken: int) -> int:
        """The run's checkpoint holds the actor's messages up to id `taken`: those the store kept after it (taken
        by an earlier learner, or posted as it died) come next. The id of the newest of them (`taken`: none)."""
        self.cursor = self.taken = taken
        return max(taken, self.store.newest_actor_message(run_id=self.run_id))

    def checkpointed(self, taken: int) -> None:
        """A checkpoint holds the messages up to id `taken`: the store forgets those before it."""
        if taken > 0:
            self.store.forget_actor_messages(run_id=self.run_id, claim=self.claim, checkpointed_id=taken)

    def send_policy(self, modules: dict[str, dict[str, Any]]) -> None:
        """pi's weights to the checkpoint store, then their version to the actor."""
        save_checkpoint(self.policy_url, {"version": self.policy_version + 1, "claim": self.claim, "modules": modules})
        published = self.store.publish_actor_policy(run_id=self.run_id, claim=self.claim)
        if published is not None:  # (None: the run was claimed again, and this learner leaves it at its next step)
            self.policy_version = published

    def next_message(self, timeout: float) -> ActorMessage | None:
        """The actor's next message within `timeout` seconds, or None; ActorError for its failure."""
        deadline = time.monotonic() + timeout
        while not self.buffer:
            if time.monotonic() - self.fetched_at >= LINK_POLL_SECONDS / 2:
                self._fetch()
                continue
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            time.sleep(min(remaining, LINK_POLL_SECONDS / 2))
        self.taken, message = self.buffer.popleft()
        if isinstance(message, Failure):  # (its own error on the first line: the run's reason)
            raise ActorError(f"the actor failed: {raised(message.traceback)}\n{message.traceback}")
        if isinstance(message, EpisodeStart | Transition):
            self.display = message.display
        return message

    def _fetch(self) -> None:
        self.fetched_at = time.monotonic()
        try:
            rows = self.store.take_actor_messages(run_id=self.run_id, after_id=self.cursor)
        except Exception as error:  # the store away: nothing new (the run's own outage handling waits it out)
            if is_transient(error):
                return
            raise
        for row in rows:
            self.buffer.append((row.id, decode_message(row.kind, row.payload, row.observation_png, row.display_png)))
            self.cursor = row.id

    def _keep_alive(self) -> None:
        while not self.closed.wait(KEEPALIVE_SECONDS):
            with contextlib.suppress(Exception):
                self.store.learner_keepalive(run_id=self.run_id, claim=self.claim)

    def close(self) -> None:
        """Let go of the actor (it holds the arm and waits for the next learner). Once only."""
        if self.closed.is_set():
            return
        self.closed.set()
        with contextlib.suppress(Exception):
            self.store.close_actor_link(run_id=self.run_id, claim=self.claim)


class ActorProcess(RemoteActor):
    """The learner's handle on the actor beside it: a child process (`serve_child`) linked through the store as a
    remote actor is, so that its steps are kept until a checkpoint holds them and a learner that takes the run
    over after a crash trains on them. Once this learner's process is gone the actor holds the arm and exits."""

    def __init__(
        self, store: Store, settings: ActorSettings, *, claim: int, checkpoint_file: str, heartbeat: Any = None
    ) -> None:
        """`store`: the learner's own (the actor opens `settings.database_url` itself)."""
        self.settings = settings
        self.process: Any = None
        super().__init__(
            store, run_id=settings.run_id, claim=claim, checkpoint_file=checkpoint_file, heartbeat=heartbeat
        )

    def _wait_for_actor(self, heartbeat: Any) -> None:
        """Start the actor (the link is open) and wait until it has announced itself: ActorError with its own error
        in one line when it fails to start, or after START_SECONDS."""
        context = multiprocessing.get_context("spawn")
        started, child_end = context.Pipe(duplex=False)
        self.process = context.Process(
            target=serve_child, args=(self.settings, self.policy_url, os.getpid(), child_end),
            name=f"actor-run-{self.run_id}", daemon=True,
        )  # fmt: skip
        self.process.start()
        child_end.close()
        deadline = time.monotonic() + START_SECONDS
        try:
            while not started.poll(LINK_POLL_SECONDS * 4):
                if not self.process.is_alive():
                    raise ActorError(f"the actor exited before it started (code {self.process.exitcode})")
                if time.monotonic() > deadline:
                    raise ActorError(f"the actor did not start within {START_SECONDS:.0f} s")
                if heartbeat is not None:
                    heartbeat()
            try:
                failure = started.recv()
            except EOFError:
                raise ActorError("the actor exited before it started") from None
        finally:
            started.close()
        if failure is not None:
            raise ActorError(f"the actor failed to start: {raised(failure)}")

    def next_message(self, timeout: float) -> ActorMessage | None:
        """The actor's next message within `timeout` seconds, or None; ActorError for its failure or its end."""
        message = super().next_message(timeout)
        if message is None and not self.process.is_alive():
            message = super().next_message(LINK_POLL_SECONDS)  # (its last messages, posted as it ended)
            if message is None:
                raise ActorError(f"the actor exited (code {self.process.exitcode})")
        return message

    def close(self) -> None:
        """Close the link (the actor holds the arm and exits); wait for it (a few seconds), else end it."""
        super().close()
        process = self.process
        if process is None:
            return
        process.join(timeout=10)
        if process.is_alive():
            process.terminate()
            process.join(timeout=5)
