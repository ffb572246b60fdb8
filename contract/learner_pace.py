"""Whether a real-time run's learner keeps up with its robot: the SAC updates it fits between the robot's steps
against the `updates_per_step` the run asks for.

The real-time runner records PACE_METRIC at every log interval: the updates per robot step over the interval's
steps after the warm-up. When the figure has stayed below BEHIND_SHARE of `updates_per_step` for BEHIND_SECONDS
of wall time, the learner cannot keep up: the run page and `GET /api/runs/{id}` say so with the run's own
figures ("84 px and 32 filters on this CPU give 0.6 updates a robot step") and suggest the robot preset that fits
(TrainConfig.cpu_robot()'s networks). An interval's wall time is its env steps over the recorded
`perf/steps_per_second`. No torch: the page and the API hand it the run's recorded metrics.
"""

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from contract.config import TrainConfig, robot_preset_for
from contract.store import Store

PACE_METRIC = "perf/updates_per_robot_step"
"""SAC updates per robot step over one log interval (the real-time runner's)."""
SPEED_METRIC = "perf/steps_per_second"
"""Env steps a second over one log interval (the trainer's), which gives the interval's wall time."""
BEHIND_SHARE = 0.5
"""A learner below this share of updates_per_step is behind."""
BEHIND_SECONDS = 60.0
"""How long it must stay behind before the page says it cannot keep up."""
NETWORK_FIELDS = ("image_size", "conv_filters")
"""What sets an update's cost: the fields the cause names and the suggestion changes."""


@dataclass(frozen=True)
class PaceSample:
    """One log interval of a real-time run."""

    step: int
    """The env step the interval ended at."""
    updates_per_robot_step: float
    seconds: float
    """The interval's wall time."""


@dataclass(frozen=True)
class LearnerPace:
    """How a real-time run's learner keeps up with its robot."""

    updates_per_robot_step: float
    """The latest interval's figure."""
    updates_per_step: int
    """What the run asks for."""
    behind_seconds: float
    """How long the figure has stayed below BEHIND_SHARE of updates_per_step (0: it is not below)."""
    behind: bool
    """Behind for at least BEHIND_SECONDS: the learner cannot keep up."""
    message: str
    """When behind, what the page says: that the learner cannot keep up, for how long, and the cause."""
    cause: str
    """When behind, the run's own figures: "84 px and 32 filters on this CPU give 0.6 updates a robot step"."""
    suggestion: str
    """When behind, what fits: the preset's fields, or another learner."""
    suggested_fields: dict[str, Any] = field(default_factory=dict)
    """The config fields the suggestion sets (empty when the run has them already)."""


def pace_samples(pace: Sequence[tuple[int, float]], speed: Sequence[tuple[int, float]]) -> list[PaceSample]:
    """The recorded (step, value) series of PACE_METRIC and SPEED_METRIC, oldest first, as samples: each
    interval's wall time is its steps (since the speed's previous record) over its speed."""
    speeds = sorted(speed)
    previous = {step: speeds[index - 1][0] if index else 0 for index, (step, _value) in enumerate(speeds)}
    rate = dict(speeds)
    samples = []
    for step, value in sorted(pace):
        seconds = (step - previous[step]) / rate[step] if rate.get(step, 0.0) > 0 else 0.0
        samples.append(PaceSample(step=step, updates_per_robot_step=value, seconds=seconds))
    return samples


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.0f} min"


def _device_words(device: str) -> str:
    return "this CPU" if device == "cpu" else f"this GPU ({device})"


def learner_pace(config: Mapping[str, Any], samples: Sequence[PaceSample]) -> LearnerPace | None:
    """The pace of a run with this stored config from its samples, oldest first; None without any (a run in
    lockstep, or one still in its warm-up)."""
    if not samples:
        return None
    values = TrainConfig.from_dict(dict(config))
    wanted, latest = values.updates_per_step, samples[-1].updates_per_robot_step
    behind_seconds = 0.0
    for sample in reversed(samples):
        if sample.updates_per_robot_step >= BEHIND_SHARE * wanted:
            break
        behind_seconds += sample.seconds
    behind = behind_seconds >= BEHIND_SECONDS
    if not behind:
        return LearnerPace(latest, wanted, behind_seconds, False, "", "", "")
    cause = (
        f"{values.image_size} px and {values.conv_filters} filters on {_device_words(values.device)} give "
        f"{latest:.1f} updates a robot step"
    )
    message = (
        f"The learner cannot keep up with the robot: {cause} for the last {_duration(behind_seconds)}, below "
        f"half of the {wanted} the run asks for (updates_per_step)."
    )
    preset = robot_preset_for("cpu")
    fits = {name: preset.fields[name] for name in NETWORK_FIELDS if preset.fields[name] != getattr(values, name)}
    if fits:
        said = ", ".join(f"{name} {value}" for name, value in fits.items())
        suggestion = f"The preset that fits is TrainConfig.{preset.name}(): {said}"
        if "image_size" in fits:
            suggestion += f" (with a goal set of {fits['image_size']} px)"
    else:
        suggestion = (
            f"The smallest robot preset's networks are too much for this learner: give the run a GPU learner "
            f"(device cuda) or a host with more free cores, or fewer updates_per_step (now {wanted})"
        )
    return LearnerPace(latest, wanted, behind_seconds, True, message, cause, suggestion + ".", fits)


def run_pace(store: Store, run_id: int, config: Mapping[str, Any]) -> LearnerPace | None:
    """learner_pace of a stored run, from its recorded metrics (None for a config no learner could train)."""
    names = (PACE_METRIC, SPEED_METRIC)
    series: dict[str, list[tuple[int, float]]] = {name: [] for name in names}
    for metric in store.metrics(run_id=run_id, names=names):
        series[metric.name].append((metric.step, metric.value))
    try:
        return learner_pace(config, pace_samples(series[PACE_METRIC], series[SPEED_METRIC]))
    except (TypeError, ValueError):
        return None
