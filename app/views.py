"""What more than one router shows: a run as the API and the pages show it, the simulated tasks' settings, the
metrics a comparison may plot, and a run's evaluated policies. Routers import these, never each other."""

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from app.schemas import (
    EvaluatedPoliciesOut,
    EvaluatedPolicyOut,
    RobotStatusOut,
    RunDetail,
    RunOut,
    TaskSettingsOut,
    row_with,
)
from contract.algorithms import ALGORITHM_SPECS
from contract.checkpoint_location import (
    BEST_POLICY_FILENAME,
    FILENAME,
    LAST_EVAL_POLICY_FILENAME,
    POLICIES_INDEX,
    POLICY_FILENAME,
    is_remote,
    run_folder,
)
from contract.config import TrainConfig
from contract.effort import run_effort
from contract.envs import SIM_TASK_SETTINGS
from contract.learner_pace import run_pace
from contract.reward_health import AnsweredQuestion, Verdict, reward_verdict
from contract.settings import Settings
from contract.store import QueryStatus, RobotStatus, Run, Store

# The metrics a comparison may plot, served to the compare page (not retyped there).
COMPARE_METRICS = {
    "eval/success_rate": "Evaluation success rate",
    "eval/return": "Evaluation return",
    "eval/classifier_return": "Classifier return Σ fψ",
    "queries/asked": "Queries asked",
    "reward/acc_replay": "Classifier accuracy on replay frames",
}


def run_out(store: Store, run: Run, waiting: dict[int, str] | None = None) -> RunOut:
    return RunOut.model_validate(row_with(run, **_run_values(store, run, waiting)), from_attributes=True)


def _run_values(store: Store, run: Run, waiting: dict[int, str] | None = None) -> dict[str, Any]:
    """What RunOut shows beside the run's columns: its query counts, latest metrics, why it waits."""
    if waiting is None and run.status == "queued":
        waiting = store.queue_report()
    return {
        "queries": store.query_counts(run_id=run.id),
        "success_rate": store.latest_metric(run_id=run.id, name="eval/success_rate"),
        "steps_per_second": store.latest_metric(run_id=run.id, name="perf/steps_per_second"),
        "eta_seconds": store.latest_metric(run_id=run.id, name="perf/eta_seconds"),
        "waiting_reason": (waiting or {}).get(run.id),
        "asks_queries": bool(getattr(ALGORITHM_SPECS.get(run.algorithm), "queries", False)),
    }


def run_detail(store: Store, run: Run) -> RunDetail:
    values = {
        **_run_values(store, run), "latest_rollout": store.latest_rollout(run_id=run.id),
        "effort": run_effort(store, run.id),
    }  # fmt: skip
    config = run.config_values()
    values["learner_pace"] = run_pace(store, run.id, config)
    robot = store.robot_status(run_id=run.id)
    values["robot"] = None if robot.actor_seen_at is None else robot_status_out(robot, run, store)
    return RunDetail.model_validate(row_with(run, **values, config=config), from_attributes=True)


def robot_status_out(status: RobotStatus, run: Run, store: Store, *, judged: bool = True) -> RobotStatusOut:
    """A run's robot controls as the API shows them, with whether the run asks for a person's help (`judged`
    False: not judged, False; the take-over's answers, sent ten times a second, skip the verdict's reads)."""
    asks = judged and reward_health_of(store, run).verdict.asks_for_help
    return RobotStatusOut.model_validate(
        row_with(status, run_name=run.name, asks_for_help=asks), from_attributes=True
    )


ANSWERS_READ = 50
"""The newest answered questions read for the reward's verdict (it looks at fewer)."""
HEALTH_SERIES = ("reward/agreement_with_answers", "eval/classifier_return", "eval/success_rate")


@dataclass(frozen=True)
class RewardHealth:
    verdict: Verdict
    answered: int
    """Answered questions the verdict read (those about states after the warm-up)."""
    warm_up_steps: int


def reward_health_of(store: Store, run: Run) -> RewardHealth:
    """contract.reward_health's verdict on the run, from its newest answers and its recorded metrics."""
    warm_up_steps = int(run.config_values().get("initial_random_steps", TrainConfig.initial_random_steps))
    rows = store.list_queries(run_id=run.id, status=QueryStatus.ANSWERED, limit=ANSWERS_READ)
    answered = [
        AnsweredQuestion(env_step=row.env_step, score=row.score, answer=bool(row.answer)) for row in reversed(rows)
    ]
    series: dict[str, list[tuple[int, float]]] = {name: [] for name in HEALTH_SERIES}
    for metric in store.metrics(run_id=run.id, names=HEALTH_SERIES):
        series[metric.name].append((metric.step, metric.value))
    verdict = reward_verdict(
        answered=answered, agreement=series["reward/agreement_with_answers"],
        classifier_return=series["eval/classifier_return"], success_rate=series["eval/success_rate"],
        warm_up_steps=warm_up_steps,
    )  # fmt: skip
    return RewardHealth(verdict, sum(q.env_step > warm_up_steps for q in answered), warm_up_steps)


def task_settings_out() -> dict[str, TaskSettingsOut]:
    """SIM_TASK_SETTINGS as the API and the New run page serve it."""
    return {
        env_id: TaskSettingsOut.model_validate(task, from_attributes=True) for env_id, task in SIM_TASK_SETTINGS.items()
    }


# A run's files (contract/checkpoint_location.py: <RAQ_CHECKPOINT_URL>/run-<id>/): policy.pt holds the actor and
# its encoder with the run's config; checkpoint.pt everything (replay buffer included).
POLICY_FILES = (POLICY_FILENAME, FILENAME)
# The policies the evaluations judged: the latest evaluation's, and the best-scoring one's (learner/train.py).
EVALUATED_POLICY_FILES = {"last_eval": LAST_EVAL_POLICY_FILENAME, "best": BEST_POLICY_FILENAME}


def evaluated_policies(settings: Settings, run_id: int) -> EvaluatedPoliciesOut:
    """The run's evaluated policies with their steps and scores (policies.json beside its checkpoint)."""
    index = _read_index(run_folder(settings.resolved_checkpoint_url, run_id)) or {}
    found = {}
    for which in EVALUATED_POLICY_FILES:
        entry = index.get(which)
        if isinstance(entry, dict) and isinstance(entry.get("step"), int):
            found[which] = EvaluatedPolicyOut(
                step=entry["step"], success_rate=entry.get("success_rate"), evaluated_return=entry.get("return"),
                url=f"/api/runs/{run_id}/policy?which={which}",
            )  # fmt: skip
    return EvaluatedPoliciesOut(last_eval=found.get("last_eval"), best=found.get("best"))


def _read_index(folder: str) -> dict | None:
    try:
        if not is_remote(folder):
            return json.loads((Path(folder) / POLICIES_INDEX).read_bytes())
        import fsspec

        with fsspec.open(f"{folder}/{POLICIES_INDEX}", "rb") as handle:
            return json.loads(handle.read())
    except (FileNotFoundError, ValueError):
        return None


def list_run_outs(store: Store, *, archived: bool | None = False) -> list[RunOut]:
    waiting = store.queue_report()
    return [run_out(store, run, waiting) for run in store.list_runs(archived=archived)]
