"""Training curves: a run's metrics after a step, grouped by name."""

import math
from typing import Annotated

from fastapi import APIRouter, HTTPException, Query

from app.deps import ReadAuth, RunId, StoreDep
from app.schemas import MetricsOut, errors
from contract.store import INT64_MAX

router = APIRouter(prefix="/api/runs", tags=["metrics"], responses=errors(401))

MAX_NAMES = 100


@router.get("/{run_id}/metrics", response_model=MetricsOut, responses=errors(404))
def run_metrics(
    run_id: RunId,
    store: StoreDep,
    _auth: ReadAuth,
    since_step: Annotated[int, Query(ge=-1, le=INT64_MAX, description="Only points with step > since_step.")] = -1,
    names: Annotated[
        list[str] | None,
        Query(description=f"Metric names; repeat the parameter or separate with commas (at most {MAX_NAMES})."),
    ] = None,
) -> MetricsOut:
    store.get_run(run_id=run_id)
    wanted = [name.strip() for value in names for name in value.split(",") if name.strip()] if names else None
    if wanted is not None and len(wanted) > MAX_NAMES:
        raise HTTPException(
            status_code=422,
            detail=[{"loc": ["query", "names"], "msg": f"at most {MAX_NAMES} names", "type": "too_long"}],
        )
    series: dict[str, list[list[int | float]]] = {}
    last_step = since_step
    for metric in store.metrics(run_id=run_id, since_step=since_step, names=wanted):
        last_step = max(last_step, metric.step)
        if math.isfinite(metric.value):
            series.setdefault(metric.name, []).append([metric.step, metric.value])
    return MetricsOut(run_id=run_id, last_step=last_step, series=series)
