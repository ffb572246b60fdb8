"""The acting policy handed to a real-time actor (robot/drive/actor.py; the contract: contract/actor_messages.py's
`Acting`): a CPU copy of pi with its warm-up and exploration noise, loaded with the learner's newest weights as they
come.

Before the warm-up's end or the first weights it acts uniformly at random; then it samples pi (both following the
episode's coloured noise, when the run has one: learner/exploration.py); in an evaluation episode it takes pi's
mean action.
"""

from typing import Any

import numpy as np
import torch

from contract.actor_messages import Acting
from contract.config import TrainConfig
from learner.checkpoint import load_checkpoint
from learner.exploration import EpisodeNoise, warm_up_action
from learner.sac import SACAgent


class SacActing:
    """pi's copy in the actor's process, its random draws seeded by the run."""

    def __init__(self, config: TrainConfig, action_dims: int) -> None:
        torch.set_num_threads(1)  # (the robot's clock before the learner's updates)
        self.config, self.action_dims = config, action_dims
        self.agent = SACAgent.for_run(config, action_dims)
        self.has_policy = False
        self.generator = torch.Generator().manual_seed(config.seed)
        self.noise = (  # coloured exploration noise per episode, from the generator; None: i.i.d. (SAC's)
            EpisodeNoise(config.exploration_noise_beta, config.episode_steps, action_dims, self.generator)
            if config.exploration_noise_beta > 0
            else None
        )
        self.rng = np.random.default_rng([config.seed, 1])

    def load(self, modules: dict[str, dict[str, Any]]) -> None:
        for name, module in self.agent.modules().items():
            if name in modules:
                module.load_state_dict(modules[name])
        self.has_policy = True

    def go_on_from(self, step: int) -> None:
        self.generator.manual_seed(self.config.seed * 1_000_003 + step)
        self.rng = np.random.default_rng([self.config.seed, 1, step])

    def episode_begins(self) -> None:
        if self.noise is not None:
            self.noise.restart()

    def act(self, observation: np.ndarray, *, step: int, evaluation: bool) -> np.ndarray:
        if evaluation:
            return self.agent.act_batch(observation[None], deterministic=True)[0]
        noise = None if self.noise is None else self.noise.next()
        if step < self.config.initial_random_steps or not self.has_policy:
            return warm_up_action(noise, self.rng, self.action_dims)
        eps = None if noise is None else noise[None]
        return self.agent.act_batch(observation[None], deterministic=False, generator=self.generator, noise=eps)[0]


SAC_ACTING = Acting(policy=SacActing, read_weights=load_checkpoint)
"""How every actor acts: with SAC's pi, its weights read from the learner's policy file."""
