"""A verdict on a run's reward, from what a real run measures: the person's answers to its questions (and what
f_psi rated each asked state), f_psi's agreement with those answers, the trend of the classifier's return, and
eval success where the env reports it.

It says whether the run is learning, stuck, or too young to tell, and what to do about it. Only evidence from
after the warm-up counts: the warm-up's states come from random actions and its f_psi is barely trained, so they
say nothing about the policy or its reward. A state is "rated a success" only when f_psi gives it p > 0.5 as the
pages show p (to the percent): a state shown as p = 50% is not. No torch, no store: the run page and the API hand
it the run's recorded metrics and answered queries.
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from contract.config import FEWEST_GOAL_IMAGES

Level = Literal["learning", "stuck", "watch", "too early"]
Series = Sequence[tuple[int, float]]
"""(env step, value) pairs of one metric, oldest first."""

RECENT_QUERIES = 10
"""Answered questions the verdict looks back over."""
MIN_QUERIES = 3
"""Answered questions before the answers say anything."""
LOW_AGREEMENT = 0.6
"""f_psi's agreement with the answers below which the goal photos and the camera likely disagree."""
FLAT_TREND = 0.05
"""A classifier return that moved less than this share of its range over the recent half is flat."""


@dataclass(frozen=True)
class AnsweredQuestion:
    """One answered question: the env step of the asked state, f_psi's logit for it when it was asked, and the
    person's answer."""

    env_step: int
    score: float
    answer: bool

    @property
    def probability(self) -> float:
        """f_psi's p that the asked state is a success: sigmoid(score)."""
        return 1.0 / (1.0 + math.exp(-max(-50.0, min(50.0, self.score))))

    @property
    def rated_success(self) -> bool:
        """f_psi gave the state p > 0.5, as the pages show p (to the percent)."""
        return round(100 * self.probability) > 50


@dataclass(frozen=True)
class Verdict:
    level: Level
    """learning, stuck, watch (a warning sign), or too early to tell."""
    summary: str
    """What the measurements say, in one sentence."""
    advice: str
    """What to do about it ("" when nothing needs doing)."""
    asks_for_help: bool = False
    """No asked state has been a success lately: a person's hands (a take-over, on a robot) would show the way."""


def trend(series: Series) -> float:
    """The mean of the recent half of a series minus that of the older half (0 for fewer than 4 points)."""
    values = [value for _, value in series]
    if len(values) < 4:
        return 0.0
    half = len(values) // 2
    return sum(values[half:]) / (len(values) - half) - sum(values[:half]) / half


def reward_verdict(
    *, answered: Sequence[AnsweredQuestion], agreement: Series = (), classifier_return: Series = (),
    success_rate: Series = (), target_success: float = 0.9, warm_up_steps: int = 0,
) -> Verdict:  # fmt: skip
    """The verdict on a run's reward; `answered` oldest first, each series as the run recorded it. Questions about
    states and records of env steps up to `warm_up_steps` (the run's initial_random_steps) are left out."""
    in_warm_up = [question for question in answered if question.env_step <= warm_up_steps]
    answered = [question for question in answered if question.env_step > warm_up_steps]
    agreement, classifier_return, success_rate = (
        [(step, value) for step, value in series if step > warm_up_steps]
        for series in (agreement, classifier_return, success_rate)
    )
    recent = answered[-RECENT_QUERIES:]
    yes = sum(question.answer for question in recent)
    rated_success = sum(question.rated_success for question in recent)
    best_success = max((value for _, value in success_rate), default=None)
    last_success = success_rate[-1][1] if success_rate else None

    if last_success is not None and last_success >= target_success:
        return Verdict("learning", f"eval success is {last_success:.0%}: the skill is learned.", "")
    if len(recent) >= MIN_QUERIES and yes == 0 and rated_success >= 0.8 * len(recent):
        rated = "each" if rated_success == len(recent) else f"{rated_success}"
        return Verdict(
            "stuck",
            f"f_psi rated {rated} of the last {len(recent)} asked states a success (p > 0.5) and all were answered "
            "no: the policy is exploiting the classifier.",
            "Ask more often (a lower query_every) and weigh the no answers more among f_psi's negatives (a higher "
            "no_answer_share than its 0.25), and add goal photos that show the finished task from the camera's view.",
            asks_for_help=True,
        )
    if len(agreement) and len(answered) >= 2 * MIN_QUERIES and agreement[-1][1] < LOW_AGREEMENT:
        return Verdict(
            "stuck",
            f"f_psi agrees with only {agreement[-1][1]:.0%} of your answers: it has learned something other than "
            "what you call a success.",
            "Check that the goal photos are framed like the camera's view (the goal set's Framing panel) and show "
            f"only successes; more goal photos ({FEWEST_GOAL_IMAGES} or more) help.",
        )
    if len(recent) >= MIN_QUERIES and yes == 0:
        flat = _flat(classifier_return)
        moving = "and the classifier's return is flat" if flat else "though the classifier's return still moves"
        return Verdict(
            "stuck" if flat and len(answered) >= RECENT_QUERIES else "watch",
            f"none of the last {len(recent)} asked states was a success {moving}: the policy has not reached the "
            "goal yet.",
            "On a robot, take over on the run page and show it the way to the goal now and then. Else, if it stays "
            "so, give goal photos closer to what the robot can reach, a longer run, or a scene reset that starts "
            "nearer the goal.",
            asks_for_help=True,
        )
    if best_success:
        return Verdict("learning", f"eval success reached {best_success:.0%}: the reward leads toward the goal.", "")
    if yes:
        return Verdict("learning", f"{yes} of the last {len(recent)} asked states were successes.", "")
    if in_warm_up and not answered:
        return Verdict(
            "too early",
            f"the {len(in_warm_up)} answers so far are about the warm-up's random states (up to step "
            f"{warm_up_steps:,}), which say nothing about the policy; the verdict waits for its own states.",
            "",
        )
    return Verdict("too early", "too few answers and evaluations yet to judge the reward.", "")


def _flat(series: Series) -> bool:
    values = [value for _, value in series]
    if len(values) < 4:
        return False
    spread = max(values) - min(values)
    return spread == 0 or abs(trend(series)) < FLAT_TREND * spread
