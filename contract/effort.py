"""What a run has cost the person so far: the answers given and the time spent answering, the scene resets and the time
the robot waited for them, the time they drove the robot by hand, and the person's minutes in all. From the store's
timestamps only (the database's clock), so the run page, the API and the bench scripts count alike.

Answering time runs from the moment a page was first served the question (GET /api/queries/next stamps
`shown_at`) to its answer, each capped at ANSWER_CAP_SECONDS so that a question left open in an idle tab counts
no more than a slow answer; an answer given without a page (an automated labeller through the API) takes no
person time. A reset's wait runs from the actor's request to the person's Ready: the robot's wait is counted
whole, the person's share of it capped at RESET_CAP_SECONDS per reset. A take-over runs from the person's first
action to their last (contract/store/robots.py: TAKEOVER_GAP_SECONDS), counted whole.
"""

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from datetime import datetime
from typing import Any

from contract.store import Store

ANSWER_CAP_SECONDS = 60.0
"""The most one answer counts: from the question shown to its answer."""
RESET_CAP_SECONDS = 120.0
"""The most one scene reset counts of the person's time (the robot's wait is counted whole)."""
EFFORT_COLUMNS = (
    "person_minutes", "answers", "answer_seconds", "resets", "reset_wait_seconds", "takeovers", "takeover_seconds",
)  # fmt: skip
"""The effort's figures as bench scripts write them, one column each."""


@dataclass(frozen=True)
class PersonEffort:
    answers: int
    """Answers given (questions answered yes or no, evaluation questions included)."""
    answer_seconds: float
    """Time spent answering, each answer capped at ANSWER_CAP_SECONDS."""
    resets: int
    """Scene resets done (Ready pressed)."""
    reset_wait_seconds: float
    """How long the robot waited for those resets, in all."""
    person_minutes: float
    """The person's minutes in all: answering, each reset's wait capped at RESET_CAP_SECONDS, and driving by hand."""
    takeovers: int = 0
    """Times the person drove the robot by hand."""
    takeover_seconds: float = 0.0
    """How long they drove it, in all."""

    def columns(self) -> dict[str, Any]:
        """The figures under EFFORT_COLUMNS' names, rounded for a CSV row."""
        values = asdict(self)
        return {
            name: round(values[name], 2) if isinstance(values[name], float) else values[name] for name in EFFORT_COLUMNS
        }


def _seconds(start: datetime, end: datetime) -> float:
    return max(0.0, (end - start).total_seconds())


def person_effort(
    answer_times: list[tuple[datetime | None, datetime]], reset_times: list[tuple[datetime, datetime | None]],
    takeover_times: Sequence[tuple[datetime, datetime]] = (),
) -> PersonEffort:
    """The effort from (shown_at, answered_at) per answer, (requested_at, ready_at) per reset (a reset still
    waiting is not counted yet) and (first action, last action) per take-over."""
    answer_seconds = sum(
        min(ANSWER_CAP_SECONDS, _seconds(shown, answered)) for shown, answered in answer_times if shown is not None
    )
    waits = [_seconds(requested, ready) for requested, ready in reset_times if ready is not None]
    takeover_seconds = sum(_seconds(first, last) for first, last in takeover_times)
    person_seconds = answer_seconds + sum(min(RESET_CAP_SECONDS, wait) for wait in waits) + takeover_seconds
    return PersonEffort(
        answers=len(answer_times), answer_seconds=answer_seconds, resets=len(waits),
        reset_wait_seconds=sum(waits), person_minutes=person_seconds / 60.0, takeovers=len(takeover_times),
        takeover_seconds=takeover_seconds,
    )  # fmt: skip


def run_effort(store: Store, run_id: int) -> PersonEffort:
    """What the run has cost the person so far, read from the store."""
    return person_effort(
        store.answer_times(run_id=run_id), store.scene_reset_times(run_id=run_id),
        store.takeover_times(run_id=run_id),
    )  # fmt: skip
