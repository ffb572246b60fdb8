"""The reward methods of the paper's comparison (Sec. VI) as one table: what each one does, in one place.

The training loop, the reward classifier and the web app read these flags; none of them checks an algorithm's
name. This module imports neither torch nor the store, so the web app can read it.
"""

from dataclasses import dataclass
from typing import Any, Literal

Negatives = Literal["replay", "pool"]
EnvReward = Literal["success", "hand_distance"]


@dataclass(frozen=True)
class AlgorithmSpec:
    """What one reward method does (original-implementation.md, the per-method table)."""

    label: str
    """How the pages name it."""
    classifier: bool
    """The reward is a classifier f_psi learned from goal examples (False: the env's own figure, `env_reward`)."""
    airl: bool = False
    """f_psi is trained as VICE's AIRL discriminator sigmoid(f_psi(s) - log pi(a|s)), else plain cross-entropy."""
    queries: bool = False
    """Asks the person about the observation it rates likeliest to be a success (Sec. IV-A)."""
    negatives: Negatives = "replay"
    """replay: uniform samples of the policy's replay; pool: first-epoch observations plus the 'no' answers."""
    train_once: bool = False
    """f_psi is trained once, after the first epoch, then frozen (the naive classifier)."""
    env_reward: EnvReward = "success"
    """What the replay keeps of each s' from the env's info, and a method without a classifier is rewarded with:
    the success flag, or minus `hand_distance` (the end effector's distance to where it is in a success)."""

    @property
    def needs_goals(self) -> bool:
        """Runs need a goal set with at least one goal example."""
        return self.classifier

    @property
    def needs_env_reward(self) -> bool:
        """The env must report info[env_reward] (it is the reward)."""
        return not self.classifier

    def env_reward_of(self, info: dict[str, Any]) -> float | None:
        """The env's figure for s' that this method keeps, from the step's `info`; None when it reports none."""
        value = info.get(self.env_reward) if isinstance(info, dict) else None
        if value is None:
            return None
        return float(bool(value)) if self.env_reward == "success" else -float(value)


ALGORITHM_SPECS: dict[str, AlgorithmSpec] = {
    "vice_raq": AlgorithmSpec(
        "VICE-RAQ: goal photos + active yes/no queries (recommended)", classifier=True, airl=True, queries=True
    ),
    "vice": AlgorithmSpec("VICE: goal photos only, no queries", classifier=True, airl=True),
    "raq": AlgorithmSpec(
        "RAQ: goal photos + queries, negatives from the first epoch", classifier=True, queries=True, negatives="pool"
    ),
    "naive_classifier": AlgorithmSpec(
        "Naive classifier: trained once on goal photos", classifier=True, negatives="pool", train_once=True
    ),
    "sparse": AlgorithmSpec("Sparse: the simulator's true success reward (no goal photos)", classifier=False),
    "hand_distance": AlgorithmSpec(
        "Hand distance: minus the end effector's distance to where it is in a success (a hand-made reward, for "
        "envs that report info['hand_distance'])",
        classifier=False, env_reward="hand_distance",
    ),
}
"""Every reward method, the recommended one first."""

ALGORITHMS: tuple[str, ...] = tuple(ALGORITHM_SPECS)
