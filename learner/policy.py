"""A trained policy from a run's checkpoint (GET /api/runs/{id}/policy downloads it), for use outside the learner:

    from learner.policy import load_policy
    policy = load_policy("run-1-checkpoint.pt")          # cpu; device="cuda" works too
    action = policy.act(observation)                    # uint8 (H, W, 3) image -> action in [-1, 1]^dim(A)
    env_action = policy.env_action(observation, env)    # the same, scaled to env.action_space

The observation is resized to the run's image_size the way the learner resizes it (contract.envs.model_image).
"""

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from contract.config import TrainConfig
from contract.envs import model_image, scale_action
from learner.sac import SACAgent


class Policy:
    """The SAC actor (and its encoder) of a checkpoint, acting deterministically (the tanh of the mean) by default."""

    def __init__(
        self, agent: SACAgent, config: TrainConfig, step: int, success_rate: float | None = None,
        evaluated_return: float | None = None,
    ) -> None:  # fmt: skip
        self.agent, self.config, self.step = agent, config, step
        # what its evaluation scored (policy-last-eval.pt, policy-best.pt); None for policy.pt and checkpoints
        self.success_rate, self.evaluated_return = success_rate, evaluated_return

    def act(self, observation: Any, deterministic: bool = True) -> np.ndarray:
        image = model_image(observation, self.config.image_size)
        with torch.no_grad():
            return self.agent.act(image, deterministic=deterministic)

    def env_action(self, observation: Any, env: Any, deterministic: bool = True) -> np.ndarray:
        return scale_action(self.act(observation, deterministic), env.action_space)


def load_policy(path: str | Path, device: str = "cpu") -> Policy:
    """Load the policy of a checkpoint written by the learner (weights_only: tensors and plain values only)."""
    state = torch.load(Path(path), map_location=device, weights_only=True)
    config = replace(TrainConfig.from_dict(json.loads(state["config"])), device=device)
    actor = state["agent"]["actor"]
    last_bias = [key for key in actor if key.endswith(".bias")][-1]
    action_dim = int(actor[last_bias].shape[0]) // 2  # the actor's last layer gives mean and log std
    agent = SACAgent.for_run(config, action_dim=action_dim)
    for name, module in agent.modules().items():  # a policy file has the actor (and encoder); a checkpoint all
        if name in ("actor", "encoder"):
            module.load_state_dict(state["agent"][name])
    agent.actor.eval()
    return Policy(agent, config, int(state["step"]), state.get("success_rate"), state.get("return"))
