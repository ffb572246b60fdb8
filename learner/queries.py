"""Active query selection (Sec. IV-A): the best observation since the last query, never one asked before.

Every new observation is scored with the current f_psi when it is made. The best `capacity` of them since the
last query are kept together with the env's display render taken at that moment, so the picture a person sees
is exactly the state the model saw (and its info / success flag is that state's, not the next one's: the
original's off-by-one bug). After each classifier update the kept candidates are re-scored so that new
observations compete under the same f_psi; at query time the best kept candidate under the current f_psi is
asked. This is the exact argmax over every observation made since the last classifier update, and over the
best `capacity` of the older ones.

Strategies: "argmax" ranks by f_psi (the paper); "entropy" by the binary entropy of sigmoid(f_psi), i.e.
by -|f_psi| (the least certain first).
"""

import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

STRATEGIES = ("argmax", "entropy")


def priority(score: float, strategy: str) -> float:
    """Higher is asked first."""
    if strategy == "argmax":
        return score
    if strategy == "entropy":
        return -abs(score)
    raise ValueError(f"unknown query strategy {strategy!r}")


def digest(image: np.ndarray) -> str:
    """Identity of an observation's pixels: an image asked about once is never asked again."""
    return hashlib.sha1(np.ascontiguousarray(image).tobytes()).hexdigest()


@dataclass
class Candidate:
    """An observation, the display render of the same state, and what the env said about it."""

    score: float
    image: np.ndarray
    display: np.ndarray
    env_step: int
    info: dict[str, Any] = field(default_factory=dict)
    success: float | None = None
    key: str = ""


class QuerySelector:
    """Keeps the best candidates since the last query and picks the one to ask."""

    def __init__(self, strategy: str, capacity: int) -> None:
        if strategy not in STRATEGIES:
            raise ValueError(f"unknown query strategy {strategy!r}")
        self.strategy = strategy
        self.capacity = capacity
        self.candidates: list[Candidate] = []
        self.asked: set[str] = set()

    def _floor(self) -> float:
        """The priority a new observation must beat to be kept."""
        if len(self.candidates) < self.capacity:
            return -np.inf
        return min(priority(c.score, self.strategy) for c in self.candidates)

    def offer(
        self, score: float, image: np.ndarray, render: Callable[[], np.ndarray], env_step: int,
        info: dict[str, Any] | None = None, success: float | None = None,
    ) -> bool:  # fmt: skip
        """Consider a new observation; `render` is called (now, on the same state) only when it is kept."""
        if priority(score, self.strategy) <= self._floor():
            return False
        key = digest(image)
        if key in self.asked or any(c.key == key for c in self.candidates):
            return False
        display = np.asarray(render()).copy()
        self.candidates.append(Candidate(float(score), image.copy(), display, env_step, info or {}, success, key))
        if len(self.candidates) > self.capacity:
            worst = min(range(len(self.candidates)), key=lambda i: priority(self.candidates[i].score, self.strategy))
            self.candidates.pop(worst)
        return True

    def rescore(self, score_fn: Callable[[np.ndarray], np.ndarray]) -> None:
        """Score the kept candidates again with the current f_psi."""
        if self.candidates:
            scores = score_fn(np.stack([c.image for c in self.candidates]))
            for candidate, score in zip(self.candidates, scores, strict=True):
                candidate.score = float(score)

    def select(self) -> Candidate | None:
        """The candidate to ask about now; forgets the others (a query covers the time since the last one)."""
        if not self.candidates:
            return None
        best = max(self.candidates, key=lambda c: priority(c.score, self.strategy))
        self.candidates = []
        self.asked.add(best.key)
        return best

    def mark_asked(self, keys: set[str]) -> None:
        """Observations asked about elsewhere (e.g. read back from the store on resume): never ask them again."""
        self.asked |= keys
        self.candidates = [c for c in self.candidates if c.key not in self.asked]

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict[str, Any]:
        return {
            "asked": sorted(self.asked),
            "candidates": [
                {
                    "score": c.score,
                    "image": torch.from_numpy(c.image.copy()),
                    "display": torch.from_numpy(c.display.copy()),
                    "env_step": c.env_step,
                    "info": json.dumps(c.info),
                    "success": c.success,
                    "key": c.key,
                }
                for c in self.candidates
            ],
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.asked |= set(state["asked"])
        self.candidates = [
            Candidate(
                score=float(c["score"]),
                image=c["image"].numpy(),
                display=c["display"].numpy(),
                env_step=int(c["env_step"]),
                info=json.loads(c["info"]),
                success=c["success"],
                key=c["key"],
            )  # fmt: skip
            for c in state["candidates"]
            if c["key"] not in self.asked
        ]
