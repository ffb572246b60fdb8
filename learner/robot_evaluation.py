"""Evaluate now on a robot run: a person asks for N episodes with the policy's mean action (the run page's robot
card, or POST /api/runs/ID/robot/evaluate) and the actor takes them from the store one by one as its episodes
begin (robot/drive/actor.py); their steps carry the request's round.

The learner stores those steps in the replay like any other (robot time is precious; SAC is off-policy) and, at
each evaluation episode's end, asks the person about its last frame: a query of strategy "evaluation", outside
the query budget and the QuerySelector. Its answer is read like any answer (QueryChannel.read_answers: a yes joins
f_psi's positives; or, for a run without queries, here, where it joins nothing). The yes share of a round's
answered questions is the run's eval/success_rate, recorded at the env step at which the round's first episode
began, each time an answer of that round comes.
"""

from dataclasses import dataclass

import numpy as np

from contract.actor_messages import Transition
from contract.config import EvaluationConfig, TaskConfig
from contract.envs import encode_png, model_image, success_of
from contract.store import AnsweredQuery, QueryStatus, Store
from learner.reward import RewardModel
from learner.run_control import Counters, RunControl

EVALUATION_STRATEGY = "evaluation"
"""The strategy of a question about an evaluation episode's last frame."""
SUCCESS_RATE = "eval/success_rate"
"""The metric of a round, as the simulated tasks' evaluations name theirs (learner/evaluation.py)."""


@dataclass
class EvaluationEpisode:
    """The evaluation episode under way: its round, the env step at which it began, its steps so far."""

    round: int
    began_at: int
    length: int = 0


class RobotEvaluation:
    """A robot run's Evaluate now rounds: their episodes' last frames asked about, their answers counted."""

    def __init__(
        self, task: TaskConfig, evaluation: EvaluationConfig, *, store: Store, run_id: int,
        reward_model: RewardModel | None,
        counters: Counters, control: RunControl, reads_answers: bool,
    ) -> None:  # fmt: skip
        """Reads the run's evaluation questions asked so far (`sync`). `reads_answers`: the run has no QueryChannel,
        so the answers are read here (they join nothing)."""
        self.task, self.log_every, self.store, self.run_id = task, evaluation.log_every, store, run_id
        self.reward_model, self.counters, self.control = reward_model, counters, control
        self.reads_answers = reads_answers
        self.episode: EvaluationEpisode | None = None
        self.round_of: dict[int, int] = {}  # query id -> its round
        self.began_at: dict[int, int] = {}  # round -> the env step at which its first episode began
        self.asked: dict[int, int] = {}  # round -> questions asked
        self.answers: dict[int, dict[int, bool]] = {}  # round -> query id -> the answer read
        self.sync()

    def sync(self) -> None:
        """On (re)start: the run's evaluation questions asked so far and their answers read. A round begun before
        a restart has its rate recorded at the step of its first question (the step its episode began is gone)."""
        for query in self.store.list_queries(run_id=self.run_id, limit=1_000_000, oldest_first=True):
            if query.strategy != EVALUATION_STRATEGY:
                continue
            round_ = int((query.info or {}).get("evaluation_round", 0))
            self.round_of[query.id] = round_
            self.asked[round_] = self.asked.get(round_, 0) + 1
            self.began_at.setdefault(round_, query.env_step)
            if query.status == QueryStatus.ANSWERED and query.used_at is not None:
                self.answers.setdefault(round_, {})[query.id] = bool(query.answer)

    def episode_began(self) -> None:
        """The actor began an episode: an evaluation episode still under way was cut short (Stop robot) and asks
        nothing."""
        cut, self.episode = self.episode, None
        if cut is not None:
            self.control.event(
                f"evaluation round {cut.round}: an episode cut short after {cut.length} steps asks nothing",
                level="warning",
            )

    def take_step(self, step: Transition, *, env_step: int) -> None:
        """One of the actor's steps, env step `env_step` of the run: at an evaluation episode's end its last frame
        is asked about. Without a QueryChannel the answers are read here, every log_every steps."""
        if step.evaluation_round is not None:
            if self.episode is None:
                self.episode = EvaluationEpisode(step.evaluation_round, began_at=env_step - 1)
                self.began_at.setdefault(step.evaluation_round, env_step - 1)
            self.episode.length += 1
            if step.terminated or step.truncated or self.episode.length >= self.task.episode_steps:
                self._ask(step, env_step)
                self.episode = None
        if self.reads_answers and env_step % self.log_every == 0:
            self.read_answers()

    def _ask(self, step: Transition, env_step: int) -> None:
        assert self.episode is not None and step.observation is not None
        round_, number = self.episode.round, self.asked.get(self.episode.round, 0) + 1
        image = model_image(step.observation, self.task.image_size, self.task.env_id)
        display = image if step.display is None else step.display
        score = 0.0 if self.reward_model is None else float(self.reward_model.logits(image[None])[0])
        query = self.store.post_query(
            run_id=self.run_id, env_step=env_step, model_png=encode_png(image), display_png=encode_png(display),
            score=score, strategy=EVALUATION_STRATEGY, info={"evaluation_round": round_, "episode": number},
            ground_truth_success=success_of(step.info),
        )  # fmt: skip
        self.round_of[query.id], self.asked[round_] = round_, number
        self.control.event(
            f"evaluation round {round_}: episode {number} ended at step {env_step}; its last frame is query {query.id}"
        )

    def read_answers(self) -> None:
        """The run's new answers (a run without a QueryChannel: they join nothing), counted for the rounds."""
        answers = self.store.new_answers(run_id=self.run_id, since_seq=self.counters.answer_cursor)
        for answer in answers:
            self.counters.answer_cursor = max(self.counters.answer_cursor, answer.answer_seq)
        self.answers_read(answers)

    def answers_read(self, answers: list[AnsweredQuery]) -> None:
        """Answers as the learner read them: for each round answered anew, the yes share of its answered
        questions, recorded as eval/success_rate at the step its first episode began."""
        rounds: set[int] = set()
        for answer in answers:
            round_ = self.round_of.get(answer.query_id)
            if round_ is not None:
                self.answers.setdefault(round_, {})[answer.query_id] = answer.success
                rounds.add(round_)
        for round_ in sorted(rounds):
            answered = list(self.answers[round_].values())
            rate = float(np.mean(answered))
            step = self.began_at.get(round_, self.counters.step)
            self.store.record_metrics(run_id=self.run_id, step=step, values={SUCCESS_RATE: rate})
            self.control.event(
                f"evaluation round {round_}: {sum(answered)} of {len(answered)} answered yes (success rate "
                f"{rate:.2f}, at step {step})"
            )
