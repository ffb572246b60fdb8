"""What a learner and its real-time actor say to each other: the wire both ends of their link speak.

The actor's messages (`ActorMessage`) go to the learner in order: an episode's first observation, each step, each
change of state; `Ready` once it has made its env, `Failure` with its traceback if it fails. The learner's
(`LearnerMessage`) go the other way: where the run starts, new policy weights, keep-alives and the close. They
cross the database, where each is a row of its `kind`, its fields in order as JSON and up to two images as PNGs
(`encode_message`, `decode_message`). The actor's end is robot/drive/link.py, the learner's learner/actor_handle.py.
"""

import io
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar, Protocol

import numpy as np
from gymnasium import spaces
from PIL import Image

from contract.config import TrainConfig
from contract.envs import encode_png, jsonable

LINK_POLL_SECONDS = 0.05
"""How often each end reads the other's side of the link from the database."""


# ====================================================================== the actor's start
@dataclass
class ActorSettings:
    """What the actor process is started with."""

    config: dict[str, Any]
    """The run's TrainConfig as a dict (its networks, seed, warm-up, sizes)."""
    run_id: int
    database_url: str
    control_hz: float
    person_reset: bool
    """Ask a person to reset the scene before every episode."""


# ====================================================================== what the actor acts with
class ActingPolicy(Protocol):
    """What the actor acts with: a copy of the learner's pi and its exploration (learner/acting.py)."""

    has_policy: bool
    """Weights from the learner have been loaded."""

    def load(self, modules: dict[str, dict[str, Any]]) -> None:
        """Take the learner's newest weights (PolicyWeights.modules)."""

    def go_on_from(self, step: int) -> None:
        """The run goes on at `step` (taken over): its random draws go on from there, not again from the first."""

    def episode_begins(self) -> None:
        """A new episode: a new exploration sequence."""

    def act(self, observation: np.ndarray, *, step: int, evaluation: bool) -> np.ndarray:
        """The action in [-1, 1] for the observation at the run's env step `step`; `evaluation`: pi's mean."""


@dataclass(frozen=True)
class Acting:
    """How an actor acts, handed in by the learner's side, so that robot/ holds no network code."""

    policy: Callable[[TrainConfig, int], ActingPolicy]
    """Makes the run's acting policy from its config and its action's dimensions."""
    read_weights: Callable[[str], dict[str, Any] | None]
    """Reads a policy file the learner wrote ({"version", "claim", "modules"}), None when there is none."""


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
    person: bool = False
    """The person drove this step by hand (a take-over): `action` is theirs."""

    def outcome(self) -> tuple:
        """gymnasium's 5-tuple of the step."""
        return self.observation, self.reward, self.terminated, self.truncated, self.info


@dataclass
class StateChange:
    """The actor's state changed (ActorState: acting, waiting for reset, stopped, held safe…)."""

    kind: ClassVar[str] = "state"
    state: str


@dataclass
class SuccessMarked:
    """A person pressed the success key: the episode under way (or, at a new one's start, the one before) ended in
    a success."""

    kind: ClassVar[str] = "success"


@dataclass
class Failure:
    """The actor failed: its traceback."""

    kind: ClassVar[str] = "error"
    traceback: str


ActorMessage = EpisodeStart | Transition | StateChange | SuccessMarked
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
    cls.kind: cls for cls in (Ready, EpisodeStart, Transition, StateChange, SuccessMarked, Failure, Start,
                              PolicyWeights, KeepAlive, Close)
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


def raised(traceback_text: str) -> str:
    """What a formatted traceback says was raised: its last line ("RuntimeError: the gripper jammed")."""
    return traceback_text.strip().splitlines()[-1]


# ====================================================================== messages as rows
def encode_message(message: Any) -> tuple[str, dict[str, Any], bytes | None, bytes | None]:
    """One of the actor's messages as a row: its kind, its fields as JSON, and up to two images as PNGs (the
    observation and the display view, lossless)."""
    kind, items = message.kind, message_items(message)
    images: list[bytes] = []

    def encoded(value: Any) -> Any:
        if isinstance(value, np.ndarray) and value.dtype == np.uint8 and value.ndim == 3:
            images.append(encode_png(value))
            return {"__image__": len(images) - 1}
        if isinstance(value, np.ndarray):
            return {"__array__": value.tolist(), "dtype": str(value.dtype)}
        return jsonable(value)

    payload = {"items": [encoded(item) for item in items]}
    if len(images) > 2:
        raise ValueError(f"an actor message holds at most two images, not {len(images)}")
    images += [None] * (2 - len(images))  # type: ignore[list-item]
    return kind, payload, images[0], images[1]


def decode_message(kind: str, payload: dict[str, Any], observation: bytes | None, display: bytes | None) -> Any:
    """The message `encode_message` stored."""
    pngs = (observation, display)

    def decoded(value: Any) -> Any:
        if isinstance(value, dict) and "__image__" in value:
            data = pngs[int(value["__image__"])]
            assert data is not None
            with Image.open(io.BytesIO(data)) as image:
                return np.array(image.convert("RGB"))
        if isinstance(value, dict) and "__array__" in value:
            return np.asarray(value["__array__"], dtype=value["dtype"])
        return value

    return message_of(kind, [decoded(item) for item in payload["items"]])


def spaces_json(action_space: spaces.Box, observation_space: spaces.Box, hz: float) -> dict[str, Any]:
    """The actor's announcement: its action space (bounds per dimension), observation shape and control rate."""
    return {
        "action": {"low": action_space.low.tolist(), "high": action_space.high.tolist()},
        "observation_shape": list(observation_space.shape),
        "control_hz": float(hz),
    }


def spaces_of(announced: dict[str, Any]) -> tuple[spaces.Box, spaces.Box]:
    """The spaces `spaces_json` announced."""
    action = announced["action"]
    low, high = np.asarray(action["low"], np.float32), np.asarray(action["high"], np.float32)
    observation = spaces.Box(0, 255, tuple(announced["observation_shape"]), np.uint8)
    return spaces.Box(low, high, dtype=np.float32), observation


# ====================================================================== a robot process's state
def driving(run_id: int) -> str:
    """A robot's process's state while it drives a run's robot."""
    return f"driving run {run_id}"


def driven_run(state: str) -> int | None:
    """The run a robot's process drives, from its state (`driving`); None: none."""
    prefix, _, number = state.partition(driving(0)[:-1])
    return int(number) if not prefix and number.isdigit() else None
