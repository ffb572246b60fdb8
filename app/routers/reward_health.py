"""A run's reward health: the verdict of contract.reward_health on its answered questions and recorded metrics."""

from fastapi import APIRouter
from pydantic import BaseModel

from app.deps import ReadAuth, RunId, StoreDep
from app.schemas import errors
from contract.config import TrainConfig
from contract.reward_health import AnsweredQuestion, Level, reward_verdict
from contract.store import QueryStatus

router = APIRouter(prefix="/api/runs", tags=["metrics"], responses=errors(401))

ANSWERS_READ = 50
"""The newest answered questions read for the verdict (it looks at fewer)."""
SERIES = ("reward/agreement_with_answers", "eval/classifier_return", "eval/success_rate")


class RewardHealthOut(BaseModel):
    level: Level
    summary: str
    advice: str
    answered: int
    """Answered questions the verdict read (those about states after the warm-up)."""
    warm_up_steps: int
    """The run's warm-up (initial_random_steps): evidence up to this env step is left out."""


@router.get("/{run_id}/reward-health", response_model=RewardHealthOut, responses=errors(404))
def reward_health(run_id: RunId, store: StoreDep, _auth: ReadAuth) -> RewardHealthOut:
    """Is the reward leading the policy toward the goal? What the answers, f_psi's agreement with them, the
    classifier's return and eval success say, and what to do when the run is stuck. Only evidence from after the
    warm-up counts."""
    run = store.get_run(run_id=run_id)
    warm_up_steps = int(run.config_values().get("initial_random_steps", TrainConfig.initial_random_steps))
    rows = store.list_queries(run_id=run_id, status=QueryStatus.ANSWERED, limit=ANSWERS_READ)
    answered = [
        AnsweredQuestion(env_step=row.env_step, score=row.score, answer=bool(row.answer)) for row in reversed(rows)
    ]
    series: dict[str, list[tuple[int, float]]] = {name: [] for name in SERIES}
    for metric in store.metrics(run_id=run_id, names=SERIES):
        series[metric.name].append((metric.step, metric.value))
    verdict = reward_verdict(
        answered=answered, agreement=series["reward/agreement_with_answers"],
        classifier_return=series["eval/classifier_return"], success_rate=series["eval/success_rate"],
        warm_up_steps=warm_up_steps,
    )  # fmt: skip
    return RewardHealthOut(
        level=verdict.level, summary=verdict.summary, advice=verdict.advice,
        answered=sum(question.env_step > warm_up_steps for question in answered), warm_up_steps=warm_up_steps,
    )  # fmt: skip
