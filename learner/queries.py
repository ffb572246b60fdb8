"""The query channel between the learner and the person (Sec. IV-A, Alg. 2 lines 5-8): scoring observations,
selecting the one to ask, posting it, reading the answers, and the query budget.

Answers never block training: they are read at least every `log_every` steps and before every classifier epoch.
A "yes" joins f_psi's positives; a "no" joins its negatives only for methods whose negatives are a pool (raq):
for VICE-RAQ the observation is already a replay negative. A robot run's evaluation questions
(learner/robot_evaluation.py) are answered and read like the others but asked outside the budget.

Active query selection (Sec. IV-A): the best observation since the last query, never one asked before.

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

from contract.config import QueryConfig
from contract.envs import decode_image, encode_png, jsonable
from contract.store import AnsweredQuery, QueryStatus, Store
from learner.reward import RewardModel
from learner.robot_evaluation import EVALUATION_STRATEGY
from learner.run_control import Counters, RunControl

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


# ====================================================================== the channel
@dataclass
class Pending:
    """An observation waiting to be scored, with what a query about it needs."""

    image: np.ndarray
    render: Callable[[], np.ndarray]
    env_step: int
    info: dict[str, Any]
    success: float | None


class QueryChannel:
    """Asks about the observation f_psi rates likeliest to be a success, at most `query_budget` times."""

    def __init__(
        self, config: QueryConfig, *, store: Store, run_id: int, reward_model: RewardModel, counters: Counters,
        control: RunControl, keep_no_answers: bool, image_size: int,
    ) -> None:  # fmt: skip
        """`keep_no_answers`: a "no" joins f_psi's negatives; `image_size`: f_psi's input side."""
        self.config, self.store, self.run_id, self.image_size = config, store, run_id, image_size
        self.reward_model, self.counters, self.control = reward_model, counters, control
        self.on_answers: Callable[[list[AnsweredQuery]], None] | None = None
        """Told of every batch of answers read (a robot run's evaluation rounds count theirs)."""
        self.selector = QuerySelector(config.query_strategy, config.query_candidates)
        self.keep_no_answers = keep_no_answers
        self.asked = 0  # (evaluation questions are not asked against the budget)
        self.pending: list[Pending] = []  # observations waiting to be scored in one batch
        # every answered query's image and answer, by query id: what the page shows as the classifier's
        # agreement with the person (rebuilt from the store on resume)
        self.answered: dict[int, tuple[np.ndarray, bool]] = {}

    @property
    def budget_left(self) -> bool:
        return self.asked < self.config.query_budget

    def observe(
        self, image: np.ndarray, info: dict[str, Any], success: float | None, render: Callable[[], np.ndarray],
        deferred: bool = False,
    ) -> None:  # fmt: skip
        """Offer a new observation as a candidate; `render()` gives the display view of this same state and is
        called only if the observation is kept. Scored now, or with `deferred` (render works later: it renders from
        a state snapshot) in a batch once `query_score_batch` wait (`score_full_batch`)."""
        if not self.budget_left:
            return
        pending = Pending(image, render, self.counters.step, jsonable(info), success)
        if not deferred:
            self._offer([pending], self.reward_model.logits(image[None]))
            return
        self.pending.append(pending)

    def score_full_batch(self) -> None:
        """Score the waiting observations once there are `query_score_batch` of them. The loop calls it while the
        SAC updates run on the update thread: they only read f_psi, as scoring does."""
        if len(self.pending) >= self.config.query_score_batch:
            self.score_pending()

    def score_pending(self) -> None:
        """Score the observations waiting for a batch, under the current f_psi (before it changes)."""
        if self.pending:
            batch, self.pending = self.pending, []
            if self.budget_left:
                self._offer(batch, self.reward_model.logits(np.stack([p.image for p in batch])))

    def _offer(self, batch: list["Pending"], scores: np.ndarray) -> None:
        for pending, score in zip(batch, scores, strict=True):
            self.selector.offer(
                float(score), pending.image, pending.render, env_step=pending.env_step, info=pending.info,
                success=pending.success,
            )  # fmt: skip

    def rescore(self) -> None:
        """After a classifier update: the kept candidates under the current f_psi."""
        self.selector.rescore(self.reward_model.logits)

    def ask(self) -> None:
        """Post the best candidate since the last query (Alg. 2 line 6)."""
        self.score_pending()
        if not self.budget_left:
            return
        self.rescore()
        candidate = self.selector.select()
        if candidate is None:
            return
        query = self.store.post_query(
            run_id=self.run_id, env_step=candidate.env_step, model_png=encode_png(candidate.image),
            display_png=encode_png(candidate.display), score=candidate.score, strategy=self.config.query_strategy,
            info=candidate.info, ground_truth_success=candidate.success,
        )  # fmt: skip
        self.asked += 1
        probability = 1.0 / (1.0 + np.exp(-np.clip(candidate.score, -50, 50)))
        budget = self.config.query_budget
        self.control.event(
            f"query {query.id} posted ({self.asked}/{budget}): observation of step "
            f"{candidate.env_step}, f_psi {candidate.score:.3f} (p = {probability:.3f})"
        )
        if not self.budget_left:
            self.control.event("query budget spent: no more queries")

    def read_answers(self) -> None:
        """New answers (Alg. 2 line 8): a yes joins the positives; a no joins the pool negatives (raq) or the
        answered negatives (vice_raq with no_answer_share > 0)."""
        model = self.reward_model
        answers = self.store.new_answers(run_id=self.run_id, since_seq=self.counters.answer_cursor)
        yes = no = 0
        for answer in answers:
            image = decode_image(answer.model_png, self.image_size)
            self.answered[answer.query_id] = (image, answer.success)
            if answer.success:
                model.add_positive(image)
                yes += 1
            else:
                no += 1
                if self.keep_no_answers:
                    model.add_negative(image)
            self.counters.answer_cursor = max(self.counters.answer_cursor, answer.answer_seq)
        if answers:
            self.control.event(
                f"answers received: {yes} yes, {no} no; the classifier now has "
                f"{len(model.goals) + len(model.answered_positives)} positives"
            )
            if self.on_answers is not None:
                self.on_answers(answers)

    def sync(self) -> None:
        """On (re)start: queries this run already asked (also after the last checkpoint) count against the budget,
        evaluation questions aside, and are never asked again; those answered and used are rebuilt for the
        agreement metrics."""
        queries = self.store.list_queries(run_id=self.run_id, limit=1_000_000)
        self.asked = sum(query.strategy != EVALUATION_STRATEGY for query in queries)
        keys = set()
        for query in queries:
            self.control.tick()
            image = decode_image(self.store.query_image(query_id=query.id, resolution="model"), self.image_size)
            if query.strategy != EVALUATION_STRATEGY:
                keys.add(digest(image))
            if query.status == QueryStatus.ANSWERED and query.used_at is not None:
                self.answered[query.id] = (image, bool(query.answer))
        self.selector.mark_asked(keys)

    def agreement(self) -> dict[str, float]:
        """What f_psi now says about the answered queries (exploitation shows as high f_psi on 'no' answers):
        mean f_psi on yes and on no answers, and the fraction on the answer's side of f_psi = 0."""
        if not self.answered:
            return {}
        images = np.stack([image for image, _ in self.answered.values()])
        labels = np.array([answer for _, answer in self.answered.values()])
        logits = self.reward_model.logits(images)
        metrics = {"reward/agreement_with_answers": float(np.mean((logits > 0) == labels))}
        if labels.any():
            metrics["reward/mean_logit_answered_yes"] = float(logits[labels].mean())
        if not labels.all():
            metrics["reward/mean_logit_answered_no"] = float(logits[~labels].mean())
        return metrics

    def counts(self) -> dict[str, float]:
        """queries/asked, answered, yes, pending: the store's counts."""
        counts = self.store.query_counts(run_id=self.run_id)
        return {f"queries/{name}": float(counts.get(name, 0)) for name in ("asked", "answered", "yes", "pending")}
