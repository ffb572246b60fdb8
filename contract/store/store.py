"""The store: every read and write the learner and the server make, as keyword-only methods.

Both processes open their own `Store` on the same database URL; they share nothing else. Rows come
back detached (expire_on_commit=False); binary columns are deferred and read with the *_image methods. The
methods live with their aggregate: runs.py, queries.py, goal_sets.py, metrics.py, auth.py, robots.py,
robot_holds.py, robot_processes.py and actor_link.py, over base.py.
"""

from contract.store.actor_link import ActorLinkStore
from contract.store.auth import AuthStore
from contract.store.goal_sets import GoalSetStore
from contract.store.metrics import MetricStore
from contract.store.queries import QueryStore
from contract.store.robot_holds import RobotHoldStore
from contract.store.robot_processes import RobotProcessStore
from contract.store.runs import RunStore


class Store(
    RunStore, QueryStore, GoalSetStore, MetricStore, AuthStore, ActorLinkStore, RobotHoldStore, RobotProcessStore
):
    """The one API over the database for the learner, the server and the tools."""
