"""Training curves: a run's metrics after a step, grouped by name."""

import math
from typing import Annotated

from fastapi import APIRouter, Query

from app.deps import StoreDep
from app.schemas import MetricsOut

router = APIRouter(prefix="/api/runs", tags=["metrics"])


@router.get("/{run_id}/metrics", response_model=MetricsOut)
def run_metrics(
    run_id: int,
    store: StoreDep,
    since_step: Annotated[int, Query(description="Only points with step > since_step.")] = -1,
    names: Annotated[
        list[str] | None, Query(description="Metric names; repeat the parameter or separate with commas.")
    ] = None,
) -> MetricsOut:
    store.get_run(run_id=run_id)
    wanted = [name.strip() for value in names for name in value.split(",") if name.strip()] if names else None
    series: dict[str, list[tuple[int, float]]] = {}
    last_step = since_step
    for metric in store.metrics(run_id=run_id, since_step=since_step, names=wanted):
        last_step = max(last_step, metric.step)
        if math.isfinite(metric.value):
            series.setdefault(metric.name, []).append((metric.step, metric.value))
    return MetricsOut(run_id=run_id, last_step=last_step, series=series)
