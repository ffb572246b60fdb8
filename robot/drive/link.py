"""The actor's end of its link with a learner, through what the rest of the product shares: the database and the
checkpoint store (a folder both mount, or object storage by URL). The learner's end is learner/actor_handle.py, the
wire contract/actor_messages.py.

`StoreLink` gives the actor loop (robot/drive/actor.py) the connection and outbox it expects: a thread polls the
link (a new keep-alive, the start, the close, a newer policy: read from the checkpoint store and handed over between
the steps) and another posts the actor's messages, so the robot's clock never waits for the database.
"""

import contextlib
import os
import queue
import threading
from collections.abc import Callable
from typing import Any

from contract.actor_messages import (
    LINK_POLL_SECONDS,
    Close,
    KeepAlive,
    PolicyWeights,
    Ready,
    Start,
    encode_message,
    spaces_json,
)
from contract.store import Store

POST_SECONDS = 0.02
"""How often the actor's messages waiting to be posted go to the database (in one transaction)."""

_LEARNER_GONE = object()


class StoreLink:
    """The actor's end: `connection` (poll, recv) has the learner's messages as a pipe would (EOFError once the
    learner's process is gone); `outbox` (put) takes the actor's, posted by a thread of its own."""

    def __init__(
        self, store: Store, *, run_id: int, policy_url: str, hz: float,
        read_weights: Callable[[str], dict[str, Any] | None], parent_pid: int | None = None,
        announced: Callable[[], None] | None = None,
    ) -> None:  # fmt: skip
        """`read_weights(url)`: the policy file the learner wrote ({"version", "claim", "modules"}, or None), read
        with the learner's own code; `parent_pid`: the learner's process, the actor's parent (an actor beside it),
        whose end is the learner's; `announced()` is called once the actor's spaces are in the store."""
        self.store, self.run_id, self.policy_url, self.hz = store, run_id, policy_url, hz
        self.read_weights, self.parent_pid, self.announced = read_weights, parent_pid, announced
        self.inbox: queue.Queue[Any] = queue.Queue()
        self.outbox: queue.Queue[Any] = queue.Queue()
        self.connection = self  # (poll and recv below)
        self.closed = threading.Event()
        self.started = False
        self.learner_seen_at: Any = None
        self.policy_version = 0
        self.claim = -1  # (the run's claim when the learner started the actor)
        self.threads = [
            threading.Thread(target=self._poll_link, name="link-poll", daemon=True),
            threading.Thread(target=self._post, name="link-post", daemon=True),
        ]
        for thread in self.threads:
            thread.start()

    def poll(self) -> bool:
        return not self.inbox.empty()

    def recv(self) -> Any:
        message = self.inbox.get_nowait()
        if message is _LEARNER_GONE:
            raise EOFError("the learner's process is gone")
        return message

    def close(self) -> None:
        """Stop both threads, the actor's last messages posted first."""
        self.closed.set()
        for thread in self.threads:
            thread.join(timeout=5.0)

    def _poll_link(self) -> None:
        """The learner's side: a new keep-alive is a beat; then the start, a newer policy, the close."""
        while not self.closed.wait(LINK_POLL_SECONDS):
            if self.parent_pid is not None and os.getppid() != self.parent_pid:
                self.inbox.put(_LEARNER_GONE)
                return
            with contextlib.suppress(Exception):  # the store away: no beats, and the watchdog holds the arm
                link = self.store.actor_link(run_id=self.run_id)
                if link.learner_seen_at is not None and link.learner_seen_at != self.learner_seen_at:
                    self.learner_seen_at = link.learner_seen_at
                    self.inbox.put(KeepAlive())
                if link.start_step is not None and not self.started:
                    self.started, self.claim = True, self.store.run_claim(run_id=self.run_id)
                    self.inbox.put(Start(link.start_step, self.claim))
                if self.started and link.policy_version > self.policy_version:
                    self._load_policy(link.policy_version)
                if link.learner_closed and self.started:
                    self.inbox.put(Close())
                    return

    def _load_policy(self, published: int) -> None:
        """The policy the store says is newest (version `published`), from the checkpoint store: taken when its
        learner holds this actor's claim (a displaced learner may have written the file since)."""
        state = self.read_weights(self.policy_url)
        if state is None:
            return
        if int(state.get("claim", -1)) != self.claim:
            self.policy_version = published  # (the file is looked at again at the next version)
            return
        self.policy_version = max(published, int(state["version"]))
        self.inbox.put(PolicyWeights(state["modules"]))

    def _post(self) -> None:
        """Post what waits in the outbox, in order, every POST_SECONDS (kept while the store is away); the actor's
        Ready is its announcement."""
        waiting: list[tuple[str, dict[str, Any], bytes | None, bytes | None]] = []
        ready: Ready | None = None
        while True:
            closing = self.closed.wait(POST_SECONDS)
            while True:
                try:
                    message = self.outbox.get_nowait()
                except queue.Empty:
                    break
                if isinstance(message, Ready):
                    ready = message
                else:
                    waiting.append(encode_message(message))
            if ready is not None:
                with contextlib.suppress(Exception):  # (asked again at the next post)
                    spaces = spaces_json(ready.action_space, ready.observation_space, self.hz)
                    self.store.announce_actor(run_id=self.run_id, spaces=spaces)
                    ready = None
                    if self.announced is not None:
                        self.announced()
            if waiting:
                try:
                    self.store.post_actor_messages(run_id=self.run_id, messages=waiting)
                    waiting = []
                except Exception:
                    if closing:
                        return
            if closing:
                return
