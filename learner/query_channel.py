"""The query channel between the learner and the person (Sec. IV-A, Alg. 2 lines 5-8): scoring observations,
selecting the one to ask, posting it, reading the answers, and the query budget.

Answers never block training: they are read at least every `log_every` steps and before every classifier epoch.
A "yes" joins f_psi's positives; a "no" joins its negatives only for methods whose negatives are a pool (raq):
for VICE-RAQ the observation is already a replay negative. A robot run's evaluation questions
(learner/robot_evaluation.py) are answered and read like the others but asked outside the budget.
"""

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from contract.config import QueryConfig
from contract.envs import decode_image, encode_png, jsonable
from contract.store import AnsweredQuery, QueryStatus, Store
from learner.queries import QuerySelector, digest
from learner.reward import RewardModel
from learner.robot_evaluation import EVALUATION_STRATEGY
from learner.run_control import Counters, RunControl


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
