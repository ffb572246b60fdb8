"""The store the learner and the server share: models and keyword-only functions, no torch, no FastAPI."""

from contract.store.base import seconds_since
from contract.store.errors import Conflict, InvalidInput, NotFound, StoreError, first_line, is_transient
from contract.store.goal_sets import GoalImage
from contract.store.models import (
    INT32_MAX,
    INT64_MAX,
    GoalExample,
    GoalSet,
    LoginFailure,
    LoginSession,
    Metric,
    Query,
    QueryStatus,
    Rollout,
    Run,
    RunPhase,
    RunStatus,
)
from contract.store.queries import AnsweredQuery
from contract.store.robots import RobotStatus
from contract.store.store import Store

__all__ = [
    "first_line",
    "is_transient",
    "INT32_MAX",
    "INT64_MAX",
    "LoginFailure",
    "LoginSession",
    "AnsweredQuery",
    "Conflict",
    "GoalExample",
    "GoalImage",
    "GoalSet",
    "InvalidInput",
    "Metric",
    "NotFound",
    "Query",
    "QueryStatus",
    "RobotStatus",
    "Rollout",
    "Run",
    "RunPhase",
    "RunStatus",
    "Store",
    "StoreError",
    "seconds_since",
]
