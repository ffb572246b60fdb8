"""The one training configuration, stored as JSON with every run.

This module imports neither torch nor the store, so the web app can validate a run's config with it.
"""

from dataclasses import asdict, dataclass, fields, replace
from typing import Any, Literal, get_args, get_origin, get_type_hints

from learner.algorithms import ALGORITHMS


def _choice_fields() -> dict[str, tuple[Any, ...]]:
    """Fields typed as Literal[...] and their allowed values."""
    hints = get_type_hints(TrainConfig)
    return {name: get_args(hint) for name, hint in hints.items() if get_origin(hint) is Literal}


@dataclass
class TrainConfig:
    """Everything that defines a training run (the paper's settings unless a field says otherwise)."""

    env_id: str = "VisualPusher-v0"
    """Gymnasium id, or "module:EnvId", of an env whose observation is an RGB uint8 image."""
    algorithm: str = "vice_raq"
    """Reward method, one of learner.algorithms.ALGORITHM_SPECS: vice_raq, vice, raq, naive_classifier, sparse."""
    seed: int = 0
    """Seed for torch, numpy and the env."""
    image_size: int = 48
    """Side of the square observation the networks see, in pixels."""
    total_steps: int = 100_000
    """Environment steps to train for."""
    episode_steps: int = 100
    """Episode length (the registered time limit); no terminal on success."""

    # --- soft actor-critic (Haarnoja et al. 2018; the paper's "untuned" defaults)
    batch_size: int = 256
    """SAC minibatch size."""
    actor_lr: float = 3e-4
    """Adam learning rate of the policy."""
    critic_lr: float = 3e-4
    """Adam learning rate of the twin Q-functions (and of the shared encoder)."""
    alpha_lr: float = 3e-4
    """Adam learning rate of the entropy temperature."""
    discount: float = 0.99
    """Discount factor gamma."""
    tau: float = 5e-3
    """Polyak factor of the target Q-networks, updated every step."""
    initial_alpha: float = 1.0
    """Starting entropy temperature."""
    target_entropy: float | None = None
    """Target policy entropy; None means -dim(A)."""
    initial_random_steps: int = 1000
    """Uniform random actions before the policy acts (and before updates start)."""
    updates_per_step: int = 1
    """Gradient steps per environment step."""
    replay_capacity: int = 200_000
    """Replay buffer size in transitions (large enough that nothing is evicted in a normal run)."""

    # --- networks
    conv_filters: int = 8
    """Filters of each of the two 5x5 conv layers (8 in simulation, 32 on the real robot)."""
    hidden_dim: int = 256
    """Width of the two fully connected layers."""
    encoder: Literal["paper", "strided"] = "strided"
    """Conv net of every network: the paper's (5x5 convs + 2x2 max-pools) or 4x4 stride-2 convs (4x cheaper)."""
    shared_encoder: bool = True
    """One conv encoder for actor and critics, trained by the critic (DrQ / SAC-AE); False: one each."""
    feature_dim: int = 50
    """Shared encoder only: Linear + LayerNorm + tanh of the conv features to this size (SAC-AE, DrQ); 0: none."""
    augmentation: Literal["none", "random_shift"] = "random_shift"
    """Image augmentation for SAC updates: DrQ's random shift by up to 4 pixels (scaled to image size)."""
    precision: Literal["auto", "fp32", "bf16"] = "auto"
    """Autocast dtype of every network (SAC and f_psi); bf16 also hands them bf16 images; auto: bf16 where faster."""
    device: str = "cpu"
    """Torch device ("cpu" or "cuda")."""

    # --- reward classifier f_psi
    classifier_lr: float = 3e-4
    """Adam learning rate of the reward classifier (the paper's code: 1e-4; its appendix: 3e-4)."""
    classifier_batch_size: int = 128
    """Positives and negatives per classifier step (each)."""
    classifier_steps: int = 100
    """Classifier gradient steps per epoch (the paper's code: 10, with 1e-4 still at chance after 7K steps)."""
    epoch_steps: int = 1000
    """Environment steps per epoch: classifier training, answer reading and evaluation happen once each."""
    mixup_alpha: float = 1.0
    """Mixup lambda ~ Beta(alpha, alpha); 0 disables mixup."""
    naive_classifier_steps: int = 10_000
    """naive_classifier: gradient steps of its one-off training after the first epoch."""
    raq_initial_negatives: int = 2000
    """raq / naive_classifier: observations from the first epoch kept as negatives."""

    # --- active queries
    query_every: int = 5000
    """Environment steps between active queries (the paper: pusher 25K, door 10K, picker 1K)."""
    query_budget: int = 20
    """Queries a run may ask in all; asking stops when it is spent."""
    query_strategy: Literal["argmax", "entropy"] = "argmax"
    """argmax: highest f_psi since the last query (the paper); entropy: the least certain one."""

    # --- evaluation and checkpoints
    eval_every: int = 1000
    """Environment steps between evaluations."""
    eval_episodes: int = 5
    """Deterministic episodes per evaluation."""
    checkpoint_every: int = 10_000
    """Environment steps between checkpoints (one is also written at a clean exit)."""
    display_size: int = 256
    """Side of the larger render stored with each query and rollout for a person to look at."""
    rollout_size: int = 128
    """Side of the frames of the evaluation rollout GIF."""
    query_candidates: int = 32
    """Best-scoring observations since the last query kept with their display render; the query is the best of them."""
    log_every: int = 250
    """Environment steps between training-metric records (answers are also read this often)."""
    heartbeat_seconds: float = 5.0
    """Seconds between heartbeats to the store (a stop request is noticed this quickly)."""

    def __post_init__(self) -> None:
        errors = self.validation_errors()
        if errors:
            field, message = errors[0]
            raise ValueError(f"{field}: {message}")

    def validation_errors(self) -> list[tuple[str, str]]:
        """(field, message) for each value that cannot work."""
        errors: list[tuple[str, str]] = []
        positive_ints = (
            "image_size", "total_steps", "episode_steps", "batch_size", "updates_per_step", "replay_capacity",
            "conv_filters", "hidden_dim", "classifier_batch_size", "epoch_steps", "query_every", "eval_every",
            "checkpoint_every", "display_size", "rollout_size", "query_candidates", "log_every",
        )  # fmt: skip
        for name in positive_ints:
            if getattr(self, name) < 1:
                errors.append((name, "must be at least 1"))
        for name in ("eval_episodes", "classifier_steps", "query_budget", "initial_random_steps", "feature_dim"):
            if getattr(self, name) < 0:
                errors.append((name, "must not be negative"))
        for name in ("actor_lr", "critic_lr", "alpha_lr", "classifier_lr", "initial_alpha"):
            if not getattr(self, name) > 0:
                errors.append((name, "must be positive"))
        if not self.heartbeat_seconds > 0:
            errors.append(("heartbeat_seconds", "must be positive"))
        if not 0 < self.discount <= 1:
            errors.append(("discount", "must be in (0, 1]"))
        if not 0 < self.tau <= 1:
            errors.append(("tau", "must be in (0, 1]"))
        if self.mixup_alpha < 0:
            errors.append(("mixup_alpha", "must not be negative"))
        if self.algorithm not in ALGORITHMS:
            errors.append(("algorithm", f"must be one of {', '.join(ALGORITHMS)}"))
        for name, choices in _choice_fields().items():
            if getattr(self, name) not in choices:
                errors.append((name, f"must be one of {', '.join(map(str, choices))}"))
        if not 16 <= self.image_size <= 256:
            errors.append(("image_size", "must be between 16 and 256"))
        if not self.env_id.strip():
            errors.append(("env_id", "must name a gymnasium env"))
        return errors

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "TrainConfig":
        """Build from stored JSON; unknown keys are an error that names them."""
        known = {field.name for field in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"{unknown[0]}: unknown config field")
        return cls(**values)

    @classmethod
    def paper(cls, **overrides: Any) -> "TrainConfig":
        """The paper's code as released: its conv net, separate per network, no augmentation, fp32, and its
        classifier schedule (10 steps per epoch at lr 1e-4)."""
        faithful = cls(
            encoder="paper", shared_encoder=False, augmentation="none", precision="fp32", classifier_steps=10,
            classifier_lr=1e-4,
        )  # fmt: skip
        return replace(faithful, **overrides)
