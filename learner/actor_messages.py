"""What a learner and its real-time actor say to each other.

The actor's messages (`ActorMessage`) go to the learner in order: an episode's first observation, each step, each
change of state; `Ready` once it has made its env, `Failure` with its traceback if it fails. The learner's
(`LearnerMessage`) go the other way: where the run starts, new policy weights, keep-alives and the close. They
cross the database (learner/actor_link.py), where each is a row of its `kind` and its fields in order.
"""

from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces


# ====================================================================== the actor's
@dataclass
class Ready:
    """The actor has made (connected to) its env: its spaces."""

    kind: ClassVar[str] = "ready"
    action_space: spaces.Box
    observation_space: spaces.Box


@dataclass
class EpisodeStart:
    """An episode began: its first observation (the model's image), the reset's info and the display render."""

    kind: ClassVar[str] = "reset"
    observation: np.ndarray
    info: dict[str, Any]
    display: np.ndarray


@dataclass
class Transition:
    """One step the robot took: the action sent, what followed it, and how long after the previous step it came."""

    kind: ClassVar[str] = "step"
    action: np.ndarray
    observation: np.ndarray
    reward: float
    terminated: bool
    truncated: bool
    info: dict[str, Any]
    display: np.ndarray
    period: float | None
    """Seconds since the previous step of the episode (None: its first)."""
    evaluation_round: int | None = None
    """A step of an evaluation episode: its Evaluate now round (None: a training step)."""

    def outcome(self) -> tuple:
        """gymnasium's 5-tuple of the step."""
        return self.observation, self.reward, self.terminated, self.truncated, self.info


@dataclass
class StateChange:
    """The actor's state changed (ActorState: acting, waiting for reset, stopped, held safe…)."""

    kind: ClassVar[str] = "state"
    state: str


@dataclass
class Failure:
    """The actor failed: its traceback."""

    kind: ClassVar[str] = "error"
    traceback: str


ActorMessage = EpisodeStart | Transition | StateChange
"""What the learner takes from its actor as training goes on."""


# ====================================================================== the learner's
@dataclass
class Start:
    """The run is at `step` (its checkpoint read): the actor may begin its first episode, for the run's `claim`
    (its learner's: the robot moves only while that is the run's current claim)."""

    kind: ClassVar[str] = "start"
    step: int
    claim: int


@dataclass
class PolicyWeights:
    """pi's weights, by module name (actor, encoder), on the CPU."""

    kind: ClassVar[str] = "policy"
    modules: dict[str, dict[str, Any]] = field(repr=False)


@dataclass
class KeepAlive:
    """The learner is alive."""

    kind: ClassVar[str] = "beat"


@dataclass
class Close:
    """The learner is done with the actor: hold the arm and exit (or wait for the next learner)."""

    kind: ClassVar[str] = "close"


LearnerMessage = Start | PolicyWeights | KeepAlive | Close
MESSAGE_TYPES: dict[str, type] = {
    cls.kind: cls for cls in (Ready, EpisodeStart, Transition, StateChange, Failure, Start, PolicyWeights, KeepAlive,
                              Close)
}  # fmt: skip
"""Every message type by its kind, as rows name them."""


def message_items(message: Any) -> list[Any]:
    """A message's fields in order (a row's items)."""
    return [getattr(message, spec.name) for spec in fields(message)]


def message_of(kind: str, items: list[Any]) -> Any:
    """The message of `kind` with these fields in order."""
    return MESSAGE_TYPES[kind](*items)


class ActorError(RuntimeError):
    """The actor failed (its traceback is the message) or went away."""
