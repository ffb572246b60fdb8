"""What a runner hands the Trainer: its training envs' episodes and their steps."""

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from learner.exploration import EpisodeNoise


@dataclass
class EnvEpisode:
    """A training env and its current episode: the last observation, its replay slot, length and reward sum."""

    env: Any
    """A gymnasium env, or the real-time actor standing for its robot."""
    obs: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3), dtype=np.uint8))
    obs_slot: int = 0
    length: int = 0
    total: float = 0.0
    noise: EpisodeNoise | None = None
    """Its coloured exploration noise, drawn anew at each episode's start; None: i.i.d. (SAC's)."""

    def state_dict(self) -> dict[str, Any]:
        """What a checkpoint keeps of the episode under way (its observation is the replay's frame obs_slot)."""
        return {"obs_slot": self.obs_slot, "length": self.length, "total": self.total}

    def load_state_dict(self, state: dict[str, Any], frames: np.ndarray) -> None:
        """The episode under way at the checkpoint, its observation from the replay's `frames`."""
        self.obs_slot, self.length, self.total = int(state["obs_slot"]), int(state["length"]), float(state["total"])
        self.obs = frames[self.obs_slot].copy()


class EnvStep(NamedTuple):
    """One env step as a runner hands it over: the episode it belongs to, the action and gymnasium's 5-tuple."""

    episode: EnvEpisode
    action: np.ndarray
    outcome: tuple
    person: bool = False
    """A person drove the step by hand (a take-over): `action` is theirs."""


def env_seed(seed: int, index: int) -> int:
    """The first reset seed of training env `index`: the run's seed for the first, and for the others seeds drawn
    from (seed, index), so that runs with nearby seeds do not share env streams."""
    if index == 0:
        return seed
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


def env_rng_state(env: Any) -> dict[str, Any] | None:
    try:
        return env.unwrapped.np_random.bit_generator.state
    except AttributeError:
        return None
