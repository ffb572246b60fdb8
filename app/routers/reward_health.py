"""A run's reward health: the verdict of contract.reward_health on its answered questions and recorded metrics."""

from fastapi import APIRouter
from pydantic import BaseModel

from app.deps import ReadAuth, RunId, StoreDep
from app.schemas import errors
from app.views import reward_health_of
from contract.reward_health import Level

router = APIRouter(prefix="/api/runs", tags=["metrics"], responses=errors(401))


class RewardHealthOut(BaseModel):
    level: Level
    summary: str
    advice: str
    asks_for_help: bool
    """No asked state has been a success lately: a person's hands would show the way (a take-over, on a robot)."""
    answered: int
    """Answered questions the verdict read (those about states after the warm-up)."""
    warm_up_steps: int
    """The run's warm-up (initial_random_steps): evidence up to this env step is left out."""


@router.get("/{run_id}/reward-health", response_model=RewardHealthOut, responses=errors(404))
def reward_health(run_id: RunId, store: StoreDep, _auth: ReadAuth) -> RewardHealthOut:
    """Is the reward leading the policy toward the goal? What the answers, f_psi's agreement with them, the
    classifier's return and eval success say, and what to do when the run is stuck. Only evidence from after the
    warm-up counts."""
    health = reward_health_of(store, store.get_run(run_id=run_id))
    verdict = health.verdict
    return RewardHealthOut(
        level=verdict.level, summary=verdict.summary, advice=verdict.advice, asks_for_help=verdict.asks_for_help,
        answered=health.answered, warm_up_steps=health.warm_up_steps,
    )  # fmt: skip
