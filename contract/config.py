"""The one training configuration, stored as JSON with every run, defined in parts: the task, the method (SAC,
networks, classifier, queries), evaluation, and how the run executes. Each field's bounds sit beside it
(`bounded`); `TrainConfig.validation_errors` is one loop over them. Each part of the learner receives its own part
(`TrainConfig.sac`, `.networks`, …), while the stored JSON stays one flat object.

This module imports neither torch nor the store, so the web app can validate a run's config with it.
"""

import ast
import math
import os
import re
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, replace
from functools import cache
from pathlib import Path
from typing import Any, Generic, Literal, TypeVar, get_args, get_origin, get_type_hints

from contract.algorithms import ALGORITHMS

SEED_MAX = 2**31 - 1  # the runs.seed column (INTEGER: 32-bit on PostgreSQL); numpy and torch take any of these
# The upper bounds of the counts are what one learner can do on a workstation-class host: a run of 10^9 env steps
# takes over a year at the ~25 steps/s measured here.
STEPS_MAX = 1_000_000_000
RETIRED_FIELDS = frozenset({
    "classifier_beside_updates", "env_processes", "n_step", "reward_centering", "classifier_label_smoothing",
    "classifier_gradient_penalty",
})  # fmt: skip
"""Fields that runs stored by earlier versions may hold and that no longer change anything: dropped when read
(docs/design.md keeps what each was measured to do)."""
FIELDS_BEFORE_THEY_EXISTED: dict[str, Any] = {"critic_layer_norm": False, "exploration_noise_beta": 0.0}
"""Fields whose default now differs from what runs stored before the field existed did: a stored config without
one reads as it ran."""
DEVICE_PATTERN = re.compile(r"cpu|cuda(:(1[0-5]|[0-9]))?")
ENV_ID_PATTERN = re.compile(r"[A-Za-z0-9_.\-/]+(:[A-Za-z0-9_.\-/]+)?")
# Memory a run may take on this host: its estimate (TrainConfig.memory_estimate) must stay under this share of RAM.
MEMORY_SHARE = 0.8
Part = TypeVar("Part")


@dataclass(frozen=True)
class Bounds:
    """What values a field takes: a range, or a check of its own; `message` replaces the range's own words."""

    low: float | None = None
    """The least value allowed."""
    high: float | None = None
    """The greatest value allowed."""
    above: float | None = None
    """Values must be greater than this (an open lower bound)."""
    message: str | None = None
    """What a value out of range is told, instead of the bound it broke."""
    check: Callable[[Any], str | None] | None = None
    """Any other rule: the message for a value that breaks it, else None."""

    def error(self, value: Any) -> str | None:
        """Why `value` cannot be used, or None (None values, where a field allows them, pass)."""
        if value is None:
            return None
        if self.check is not None:
            return self.check(value)
        if self.above is not None and not value > self.above:
            return self.message or ("must be positive" if self.above == 0 else f"must be greater than {self.above:g}")
        if self.low is not None and value < self.low:
            return self.message or ("must not be negative" if self.low == 0 else f"must be at least {self.low:,}")
        if self.high is not None and value > self.high:
            high = f"{self.high:,}" if isinstance(value, int) else f"{self.high:g}"
            return self.message or f"must be at most {high}"
        return None


def bounded(default: Any, low: float | None = None, high: float | None = None, **rules: Any) -> Any:
    """A field with its default and its bounds (Bounds' low, high, above, message, check)."""
    return field(default=default, metadata={"bounds": Bounds(low, high, **rules)})


def _device_error(value: str) -> str | None:
    if not DEVICE_PATTERN.fullmatch(value):
        return "must be 'cpu', 'cuda' or 'cuda:N' (N from 0 to 15)"
    return None


def _env_id_error(value: str) -> str | None:
    if not value.strip():
        return "must name a gymnasium env"
    if len(value) > 200 or not ENV_ID_PATTERN.fullmatch(value):
        return "must be a gymnasium id or 'module:EnvId' (letters, digits, _.-/; 200 at most)"
    return None


def _algorithm_error(value: str) -> str | None:
    return None if value in ALGORITHMS else f"must be one of {', '.join(ALGORITHMS)}"


def host_memory_bytes() -> int:
    """Physical memory of this host (Linux /proc/meminfo, else sysconf)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def host_cuda_devices() -> int:
    """NVIDIA GPUs this host exposes (/dev/nvidia0, /dev/nvidia1, …), counted without importing torch."""
    return sum(1 for path in Path("/dev").glob("nvidia*") if path.name[len("nvidia") :].isdigit())


def cuda_devices_needed(device: str) -> int:
    """How many CUDA GPUs a learner must have to run on `device`: 0 for "cpu", N + 1 for "cuda:N" ("cuda": 1)."""
    if not device.startswith("cuda"):
        return 0
    return int(device.partition(":")[2] or 0) + 1


def device_need(device: str) -> str | None:
    """What a run on `device` waits for, in words ("a learner with CUDA"), or None for the CPU."""
    needed = cuda_devices_needed(device)
    if not needed:
        return None
    return "a learner with CUDA" if needed == 1 else f"a learner with at least {needed} CUDA GPUs ({device})"


@cache
def _choice_fields() -> dict[str, tuple[Any, ...]]:
    """Fields typed as Literal[...] and their allowed values."""
    hints = get_type_hints(TrainConfig)
    return {name: get_args(hint) for name, hint in hints.items() if get_origin(hint) is Literal}


@dataclass
class TaskConfig:
    """What task a run learns: the env, its seed and length."""

    env_id: str = bounded("VisualPusher-v0", check=_env_id_error)
    """Gymnasium id, or "module:EnvId" with a module in RAQ_ENV_MODULES, of an env with RGB image observations."""
    seed: int = bounded(0, 0, SEED_MAX, message=f"must be between 0 and {SEED_MAX}")
    """Seed for torch, numpy and the env (0 to 2**31 - 1)."""
    image_size: int = bounded(48, 16, 256, message="must be between 16 and 256")
    """Side of the square observation the networks see, in pixels."""
    total_steps: int = bounded(100_000, 1, STEPS_MAX)
    """Environment steps to train for."""
    episode_steps: int = bounded(100, 1, 100_000)
    """Episode length (the registered time limit); no terminal on success."""


@dataclass
class SACConfig:
    """Soft actor-critic (Haarnoja et al. 2018; the paper's "untuned" defaults)."""

    batch_size: int = bounded(256, 1, 4096)
    """SAC minibatch size."""
    actor_lr: float = bounded(3e-4, high=1.0, above=0)
    """Adam learning rate of the policy."""
    critic_lr: float = bounded(3e-4, high=1.0, above=0)
    """Adam learning rate of the twin Q-functions (and of the shared encoder)."""
    alpha_lr: float = bounded(3e-4, high=1.0, above=0)
    """Adam learning rate of the entropy temperature."""
    discount: float = bounded(0.99, high=1, above=0, message="must be in (0, 1]")
    """Discount factor gamma."""
    tau: float = bounded(5e-3, high=1, above=0, message="must be in (0, 1]")
    """Polyak factor of the target Q-networks, updated every step."""
    initial_alpha: float = bounded(1.0, high=1e6, above=0)
    """Starting entropy temperature."""
    target_entropy: float | None = bounded(None, -1e6, 1e6, message="must be between -1e6 and 1e6")
    """Target policy entropy; None means -dim(A)."""
    initial_random_steps: int = bounded(1000, 0, 1_000_000)
    """Uniform random actions before the policy acts (and before updates start)."""
    exploration_noise_beta: float = bounded(1.0, 0, 2.0)
    """Colour of the acting policy's noise over an episode, power spectrum ~ 1/f^beta (Eberhard et al. 2023; the
    warm-up's actions too): 1 pink; 0 white, SAC's i.i.d. draws; 2 red."""
    person_share: float = bounded(0.5, 0, 1)
    """Share of each SAC batch drawn from the steps a person drove by hand, once there are any (HIL-SERL's demo
    buffer, sampled half and half as RLPD does); the rest uniformly from the replay."""
    updates_per_step: int = bounded(2, 1, 100)
    """Gradient steps per environment step (with a real-time actor: at most this many; fewer when slower); 1: SAC's."""
    replay_capacity: int = bounded(200_000, 1, 10_000_000)
    """Replay buffer size in transitions (large enough that nothing is evicted in a normal run)."""


@dataclass
class NetworkConfig:
    """The conv encoder and the fully connected layers of every network."""

    conv_filters: int = bounded(8, 1, 256)
    """Filters of each of the two 5x5 conv layers (8 in simulation, 32 on the real robot)."""
    hidden_dim: int = bounded(256, 1, 4096)
    """Width of the two fully connected layers."""
    encoder: Literal["paper", "strided"] = "strided"
    """Conv net of every network: the paper's (5x5 convs + 2x2 max-pools) or 4x4 stride-2 convs (4x cheaper)."""
    shared_encoder: bool = True
    """One conv encoder for actor and critics, trained by the critic (DrQ / SAC-AE); False: one each."""
    feature_dim: int = bounded(50, 0, 4096)
    """Shared encoder only: Linear + LayerNorm + tanh of the conv features to this size (SAC-AE, DrQ); 0: none."""
    critic_layer_norm: bool = True
    """LayerNorm (no affine) after each hidden layer of the Q MLPs, before the ReLU (RLPD's critics); False: SAC's."""
    augmentation: Literal["none", "random_shift"] = "random_shift"
    """Image augmentation for SAC updates: DrQ's random shift by up to 4 pixels (scaled to image size)."""


@dataclass
class ClassifierConfig:
    """The reward classifier f_psi (Sec. IV, Alg. 2)."""

    classifier_lr: float = bounded(3e-4, high=1.0, above=0)
    """Adam learning rate of the reward classifier (the paper's code: 1e-4; its appendix: 3e-4)."""
    classifier_batch_size: int = bounded(128, 1, 4096)
    """Positives and negatives per classifier step (each)."""
    classifier_steps: int = bounded(100, 0, 100_000)
    """Classifier gradient steps per epoch (the paper's code: 10, with 1e-4 still at chance after 7K steps)."""
    epoch_steps: int = bounded(1000, 1, 1_000_000)
    """Environment steps per epoch: classifier training, answer reading and evaluation happen once each."""
    mixup_alpha: float = bounded(1.0, 0, 100.0)
    """Mixup lambda ~ Beta(alpha, alpha); 0 disables mixup."""
    no_answer_share: float = bounded(0.25, 0, 1.0)
    """VICE-RAQ: share of classifier negatives drawn from "no" answers (once there are any); 0: the paper's (replay
    only)."""
    naive_classifier_steps: int = bounded(10_000, high=1_000_000)
    """naive_classifier: gradient steps of its one-off training after the first epoch."""
    raq_initial_negatives: int = bounded(2000, high=1_000_000)
    """raq / naive_classifier: observations from the first epoch kept as negatives."""


@dataclass
class QueryConfig:
    """Active queries: which observation is asked about, how often, how many (Sec. IV-A)."""

    query_every: int = bounded(5000, 1, STEPS_MAX)
    """Environment steps between active queries (the paper: pusher 25K, door 10K, picker 1K)."""
    query_budget: int = bounded(20, 0, 100_000)
    """Queries a run may ask in all; asking stops when it is spent."""
    query_strategy: Literal["argmax", "entropy"] = "argmax"
    """argmax: highest f_psi since the last query (the paper); entropy: the least certain one."""
    query_candidates: int = bounded(32, 1, 1024)
    """Best-scoring observations since the last query kept with their display render; the query is the best of them."""
    query_score_batch: int = bounded(64, 1, 4096)
    """Observations f_psi scores together as query candidates, for envs that can snapshot their state (the
    simulated tasks; the display render of a kept one is taken from its snapshot); 1, or other envs: each at once."""

    def asks_after(self, step: int, *, asked: int) -> bool:
        """A query is asked after env step `step`, `asked` having been asked: every query_every steps while the
        budget lasts (Alg. 2 line 5)."""
        return step % self.query_every == 0 and asked < self.query_budget

    def next_query_step(self, step: int, *, asked: int) -> int | None:
        """The env step after which the next query is asked, the run being at `step`; None once the budget is
        spent."""
        if asked >= self.query_budget:
            return None
        return (step // self.query_every + 1) * self.query_every


@dataclass
class EvaluationConfig:
    """Evaluation, checkpoints and what is recorded for a person to look at."""

    eval_every: int = bounded(1000, 1, STEPS_MAX)
    """Environment steps between evaluations."""
    eval_episodes: int = bounded(5, 0, 1000)
    """Deterministic episodes per evaluation."""
    checkpoint_every: int = bounded(10_000, 1, STEPS_MAX)
    """Environment steps between checkpoints (one is also written at a clean exit)."""
    display_size: int = bounded(256, 16, 1024)
    """Side of the larger render stored with each query and rollout for a person to look at."""
    rollout_size: int = bounded(128, 16, 512)
    """Side of the frames of the evaluation rollout GIF."""
    log_every: int = bounded(250, 1, STEPS_MAX)
    """Environment steps between training-metric records (answers are also read this often)."""


@dataclass
class ExecutionConfig:
    """How the run executes on its host: device, precision, threads, pipelines, envs. None of it changes the method."""

    device: str = bounded("cpu", check=_device_error)
    """Torch device: "cpu", "cuda" or "cuda:N"; only a learner with that GPU takes the run."""
    precision: Literal["auto", "fp32", "bf16"] = "auto"
    """Autocast dtype of every network (SAC and f_psi); bf16 also hands them bf16 images; auto: bf16 where faster."""
    num_envs: int = bounded(1, 1, 64)
    """Training envs in lockstep: the policy acts for all in one batch; each env step is one loop step."""
    compile_updates: bool = False
    """Device pipeline only: torch.compile the update and the classifier step before graph capture."""
    replay_pipeline: Literal["auto", "host", "device"] = "auto"
    """Batches sampled and rewarded on the host (numpy, cached f_psi) or device (CUDA graphs); auto: GPU."""
    update_thread: Literal["auto", "on", "off"] = "auto"
    """SAC updates on a second thread while the envs step (MuJoCo leaves the GIL); auto: on unless on a GPU."""
    heartbeat_seconds: float = bounded(5.0, high=3600.0, above=0)
    """Seconds between heartbeats to the store (a stop request is noticed this quickly)."""
    control_hz: float = bounded(0.0, 0, 1000.0)
    """Real time: the env steps at this rate in an actor process of its own, never waiting for the learner; 0: a
    robot env's own rate (robot.base.RobotEnv.control_hz), any other env in lockstep with the updates."""
    policy_sync_seconds: float = bounded(1.0, high=3600.0, above=0)
    """Real time: seconds between the policy weights the learner sends its actor."""
    watchdog_seconds: float = bounded(2.0, high=60.0, above=0)
    """Real time: the actor holds the arm safe when the learner or the database has been silent this long."""
    reset_every_episode: bool = False
    """Real time: a person resets the scene before every episode (a robot env that needs it always asks)."""
    remote_actor: bool = False
    """Real time: the learner waits for the robot's own process (`raq robot ENV_ID` or `raq actor --run ID` on the
    robot's host; the learner never makes the env); False: it links to that process when one is up, else starts an
    actor beside itself."""


@dataclass
class MethodConfig(SACConfig, NetworkConfig, ClassifierConfig, QueryConfig):
    """What the method is: the reward method of ALGORITHM_SPECS and its SAC, networks, classifier and queries."""

    algorithm: str = bounded("vice_raq", check=_algorithm_error)
    """Reward method, one of contract.algorithms.ALGORITHM_SPECS: vice_raq, vice, raq, naive_classifier, sparse,
    hand_distance."""


class PartOf(Generic[Part]):
    """`config.sac` and friends: one part of a TrainConfig's values as that part (TrainConfig.part)."""

    def __init__(self, part: type[Part]) -> None:
        self.part = part

    def __get__(self, config: "TrainConfig", owner: type | None = None) -> Part:
        return config.part(self.part)


@dataclass
class TrainConfig(ExecutionConfig, EvaluationConfig, MethodConfig, TaskConfig):
    """Everything that defines a training run, stored as one flat JSON object (the paper's settings unless a field
    says otherwise): the task it runs, the method, its evaluation, and how it executes."""

    def __post_init__(self) -> None:
        errors = self.validation_errors()
        if errors:
            field, message = errors[0]
            raise ValueError(f"{field}: {message}")

    def validation_errors(self) -> list[tuple[str, str]]:
        """(field, message) for each value that cannot work: one pass over the fields' bounds and choices."""
        errors: list[tuple[str, str]] = []
        choices = _choice_fields()
        for spec in fields(self):
            value = getattr(self, spec.name)
            if isinstance(value, float) and not math.isfinite(value):
                message: str | None = "must be a finite number"
            elif spec.name in choices:
                allowed = choices[spec.name]
                message = None if value in allowed else f"must be one of {', '.join(map(str, allowed))}"
            else:
                bounds = spec.metadata.get("bounds")
                message = None if bounds is None else bounds.error(value)
            if message is not None:
                errors.append((spec.name, message))
        return errors

    def part(self, part: type[Part]) -> Part:
        """The values of one part of the configuration (SACConfig, NetworkConfig, …) as that part."""
        return part(**{spec.name: getattr(self, spec.name) for spec in fields(part)})  # type: ignore[call-overload]

    task = PartOf(TaskConfig)
    sac = PartOf(SACConfig)
    networks = PartOf(NetworkConfig)
    classifier = PartOf(ClassifierConfig)
    queries = PartOf(QueryConfig)
    evaluation = PartOf(EvaluationConfig)
    execution = PartOf(ExecutionConfig)

    def memory_estimate(self) -> int:
        """Bytes of host memory the run's images take at most: the replay's frame ring (two frames per
        transition, uint8), the query candidates with their display renders, raq's first-epoch negatives, and
        the float32 minibatches of SAC (s and s') and f_psi (positives and negatives) with room for activations."""
        frame = self.image_size * self.image_size * 3
        replay = 2 * self.replay_capacity * frame
        candidates = self.query_candidates * (frame + self.display_size * self.display_size * 3)
        candidates += self.query_score_batch * frame
        negatives = self.raq_initial_negatives * frame
        batches = (2 * self.batch_size + 2 * self.classifier_batch_size) * frame * 4 * 8
        return replay + candidates + negatives + batches

    def resource_errors(self, *, memory_bytes: int) -> list[tuple[str, str]]:
        """(field, message) when the run's own size is more than a host of `memory_bytes` allows. Which GPUs it
        needs is the learners' business (`cuda_devices_needed`): a learner claims only runs it can execute."""
        errors: list[tuple[str, str]] = []
        budget = int(memory_bytes * MEMORY_SHARE)
        needed = self.memory_estimate()
        if needed > budget:
            errors.append((
                "replay_capacity",
                f"the run would need about {needed / 2**30:,.1f} GiB for its images "
                f"(replay {self.replay_capacity:,} x 2 frames of {self.image_size}x{self.image_size}x3, query "
                f"candidates, batches); this host allows {budget / 2**30:,.1f} GiB ({MEMORY_SHARE:.0%} of its RAM)",
            ))  # fmt: skip
        return errors

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "TrainConfig":
        """Build from stored JSON (the fields of RETIRED_FIELDS dropped, those of FIELDS_BEFORE_THEY_EXISTED filled in
        where absent); unknown keys are an error that names them."""
        known = {field.name for field in fields(cls)}
        values = {name: value for name, value in values.items() if name not in RETIRED_FIELDS}
        values = {**FIELDS_BEFORE_THEY_EXISTED, **values}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"{unknown[0]}: unknown config field")
        return cls(**values)

    @classmethod
    def paper(cls, **overrides: Any) -> "TrainConfig":
        """The paper's code as released: its conv net, separate per network, no augmentation, fp32, SAC's critics,
        i.i.d. action noise and one update per env step, its classifier schedule (10 steps per epoch at lr 1e-4),
        and replay alone as f_psi's negatives."""
        faithful = cls(
            encoder="paper", shared_encoder=False, augmentation="none", precision="fp32", critic_layer_norm=False,
            updates_per_step=1, classifier_steps=10, classifier_lr=1e-4, no_answer_share=0.0,
            exploration_noise_beta=0.0,
        )  # fmt: skip
        return replace(faithful, **overrides)

    @classmethod
    def real_robot(cls, **overrides: Any) -> "TrainConfig":
        """The paper's real-robot settings (Sec. VII): 84x84 camera images, 32 filters per conv layer, a question
        every 250 env steps; no evaluation episodes, which would take robot time (give it REAL_ROBOT_GOAL_IMAGES
        goal photos)."""
        robot = cls(image_size=84, conv_filters=32, query_every=250, query_budget=50, eval_episodes=0)
        return replace(robot, **overrides)

    @classmethod
    def cpu_robot(cls, **overrides: Any) -> "TrainConfig":
        """Robot settings a CPU learner keeps up with: the simulated tasks' 48x48 images and 8 filters (the
        paper's 84 px and 32 filters cost about 10x the compute per update, too much for a few cores beside a
        5 Hz robot), with real_robot's questions (every 250 env steps, 50 in all) and no evaluation episodes; up
        to 4 SAC updates a robot step, since a 200 ms step leaves a CPU learner time for about 3 of these small
        ones even beside a second robot (docs/results.md: the stand-in's steps to 90%)."""
        robot = cls(
            image_size=48, conv_filters=8, query_every=250, query_budget=50, eval_episodes=0, updates_per_step=4
        )
        return replace(robot, **overrides)


ROBOT_PRESETS: dict[str, str] = {
    "cpu_robot": "for a CPU learner: the simulated tasks' 48 px and 8 filters, which a few cores keep up with "
    "beside a 5 Hz robot",
    "real_robot": "for a GPU learner: the paper's 84 px and 32 filters, about 10x the compute per update",
}  # fmt: skip
"""The robot presets (TrainConfig classmethods of these names), each with what it is for, in words."""


@dataclass(frozen=True)
class RobotPreset:
    """The robot settings a run on a device starts from (the New run form fills them in for a robot env)."""

    name: str
    """The TrainConfig classmethod: "cpu_robot" or "real_robot"."""
    fields: dict[str, Any]
    """The fields either robot preset sets, with this one's values (so switching presets replaces them all)."""
    description: str
    """What the preset is for, in words (ROBOT_PRESETS)."""


def robot_preset_for(device: str) -> RobotPreset:
    """The robot preset a learner on `device` keeps up with: TrainConfig.cpu_robot() for "cpu", the paper's
    TrainConfig.real_robot() for "cuda" or "cuda:N". Its fields are every field in which a robot preset differs
    from the defaults, read from the presets themselves."""
    name = "real_robot" if device.startswith("cuda") else "cpu_robot"
    defaults = asdict(TrainConfig())
    presets = {preset: asdict(getattr(TrainConfig, preset)()) for preset in ROBOT_PRESETS}
    names = sorted({f for values in presets.values() for f, value in values.items() if value != defaults[f]})
    fields_set = {field: presets[name][field] for field in names}
    return RobotPreset(name=name, fields=fields_set, description=ROBOT_PRESETS[name])


REAL_ROBOT_GOAL_IMAGES = 80
"""Goal photos the paper gave each real-robot task."""
FEWEST_GOAL_IMAGES = 10
"""Goal photos a set needs before the goal-set page stops calling them too few (the simulated tasks' results use
as many)."""

CONFIG_PARTS: dict[str, type] = {
    "task": TaskConfig, "sac": SACConfig, "networks": NetworkConfig, "classifier": ClassifierConfig,
    "queries": QueryConfig, "evaluation": EvaluationConfig, "execution": ExecutionConfig,
}  # fmt: skip
"""The parts of a TrainConfig, as the New run form and the docs group its fields (the method's: sac, networks,
classifier and queries, with `algorithm`)."""


def config_part(name: str) -> str:
    """The part a TrainConfig field belongs to ("method" for `algorithm`)."""
    for part, cls in CONFIG_PARTS.items():
        if name in cls.__dataclass_fields__:
            return part
    return "method"


@cache
def field_docs() -> dict[str, str]:
    """Each TrainConfig field's one-line docstring, read from this module's source (the docstring under it)."""
    tree = ast.parse(Path(__file__).read_text())
    docs: dict[str, str] = {}
    for node in tree.body:
        if not isinstance(node, ast.ClassDef):
            continue
        for statement, following in zip(node.body, node.body[1:], strict=False):
            if (
                isinstance(statement, ast.AnnAssign) and isinstance(statement.target, ast.Name)
                and isinstance(following, ast.Expr) and isinstance(following.value, ast.Constant)
            ):  # fmt: skip
                docs[statement.target.id] = " ".join(str(following.value.value).split())
    return docs


def config_reference() -> dict[str, list[tuple[str, Any, str]]]:
    """Per part (CONFIG_PARTS, and "method" for `algorithm`): (field, default, what it is) of every field, in the
    order the form, the API (GET /api/config) and docs/configuration.md show them."""
    docs, defaults = field_docs(), TrainConfig()
    parts: dict[str, list[tuple[str, Any, str]]] = {}
    for spec in fields(TrainConfig):
        parts.setdefault(config_part(spec.name), []).append(
            (spec.name, getattr(defaults, spec.name), docs[spec.name])
        )
    order = ["task", "method", *[part for part in CONFIG_PARTS if part != "task"]]
    return {part: parts[part] for part in order if part in parts}


def reference_markdown() -> str:
    """docs/configuration.md: every field of a run's configuration by part, with its default (`raq config`)."""
    lines = [
        "# Run configuration", "",
        "Every field of a run's configuration (`contract/config.py`), with its default. The New run form's",
        "*More settings* and `config` in `POST /api/runs` take any of them. Made by `raq config`.", "",
    ]  # fmt: skip
    for part, entries in config_reference().items():
        lines += [f"## {part}", "", "| field | default | what it is |", "| --- | --- | --- |"]
        lines += [f"| `{name}` | `{default!r}` | {doc.replace('|', '/')} |" for name, default, doc in entries]
        lines.append("")
    return "\n".join(lines)
