"""Compare runs: one metric of chosen runs, grouped by env and algorithm (the seeds of a sweep), as the mean with
its spread (min and max) at each step every run of the group recorded: the view the paper's figures give."""

from typing import Annotated

from fastapi import APIRouter, HTTPException, Query

from app.deps import ReadAuth, StoreDep
from app.schemas import CompareGroupOut, CompareOut, errors
from app.views import COMPARE_METRICS
from contract.store import INT32_MAX, Store

router = APIRouter(prefix="/api/compare", tags=["compare"], responses=errors(401))

MAX_RUNS = 50


def mean_and_spread(per_run: list[dict[int, float]]) -> list[list[float]]:
    """[step, mean, min, max, runs] at each step every run recorded (a run that stopped early ends the curve)."""
    common = sorted(set.intersection(*(set(values) for values in per_run))) if per_run else []
    points = []
    for step in common:
        values = [values[step] for values in per_run]
        points.append([float(step), sum(values) / len(values), min(values), max(values), float(len(values))])
    return points


def compare_groups(store: Store, *, run_ids: list[int], metric: str) -> list[CompareGroupOut]:
    groups: dict[str, list[int]] = {}
    for run_id in run_ids:
        run = store.get_run(run_id=run_id)
        groups.setdefault(f"{run.env_id} · {run.algorithm}", []).append(run_id)
    out = []
    for label, ids in groups.items():
        per_run = [{m.step: m.value for m in store.metrics(run_id=run_id, names=[metric])} for run_id in ids]
        out.append(CompareGroupOut(label=label, run_ids=ids, points=mean_and_spread(per_run)))
    return out


def _query_error(field: str, message: str) -> HTTPException:
    return HTTPException(status_code=422, detail=[{"loc": ["query", field], "msg": message, "type": "value_error"}])


@router.get("", response_model=CompareOut, responses=errors(404))
def compare(
    store: StoreDep,
    _auth: ReadAuth,
    runs: Annotated[str, Query(max_length=600, description="Run ids, comma-separated.", examples=["1,2,3"])],
    metric: Annotated[str, Query(description="One of " + ", ".join(COMPARE_METRICS))] = "eval/success_rate",
) -> CompareOut:
    try:
        run_ids = list(dict.fromkeys(int(part) for part in runs.split(",") if part.strip()))
    except ValueError:
        raise _query_error("runs", "run ids, comma-separated") from None
    if not run_ids or len(run_ids) > MAX_RUNS or any(not 1 <= run_id <= INT32_MAX for run_id in run_ids):
        raise _query_error("runs", f"1 to {MAX_RUNS} run ids")
    if metric not in COMPARE_METRICS:
        raise _query_error("metric", "one of " + ", ".join(COMPARE_METRICS))
    return CompareOut(metric=metric, groups=compare_groups(store, run_ids=run_ids, metric=metric))
