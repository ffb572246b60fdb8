"""One robot, one driver: the store's robot holds and the claim a takeover increases (contract/store/robot_holds.py)."""

import threading

from sqlalchemy import update

from contract.store import Store
from contract.store.models import RobotHold, RobotProcess, Run
from contract.store.robot_holds import HOLD_LAPSES_SECONDS, MOVE_WITHIN_SECONDS, robot_name

ROBOT = robot_name("robot.standin:PusherStandIn-v0")


def claimed_run(store: Store, name: str) -> tuple[int, int]:
    """A run claimed by a learner: its id and claim."""
    run = store.create_run(name=name, env_id="robot.standin:PusherStandIn-v0", algorithm="vice_raq", config={})
    claimed = store.claim_next_run(worker=f"learner-{name}")
    assert claimed is not None and claimed.id == run.id
    return run.id, claimed.claim


def age_hold(store: Store, seconds: float) -> None:
    """The hold as if last renewed `seconds` ago (by the database's clock)."""
    with store.writing() as session:
        session.execute(update(RobotHold).values(renewed_at=store._db_now(seconds)))


def test_a_claim_grows_with_each_takeover(store: Store) -> None:
    run_id, claim = claimed_run(store, "a")
    assert claim == 1
    with store.writing() as session:  # its learner stopped beating a while ago
        session.execute(update(Run).where(Run.id == run_id).values(heartbeat_at=store._db_now(120)))
    taken = store.claim_next_run(worker="learner-b")
    assert taken is not None and taken.id == run_id and taken.claim == 2
    assert store.run_claim(run_id=run_id) == 2


def test_a_second_run_of_the_robot_waits_until_the_first_lets_go(store: Store) -> None:
    first, first_claim = claimed_run(store, "first")
    second, second_claim = claimed_run(store, "second")
    assert store.take_robot(robot=ROBOT, run_id=first, claim=first_claim, holder="1@host").taken
    busy = store.take_robot(robot=ROBOT, run_id=second, claim=second_claim, holder="2@host")
    assert not busy.taken and busy.busy_with == first
    assert store.robot_holder(robot=ROBOT) == first
    assert store.may_move_robot(robot=ROBOT, holder="1@host").allowed
    assert not store.may_move_robot(robot=ROBOT, holder="2@host").allowed
    # another robot on the same host is another row
    assert store.take_robot(robot=robot_name("other:Arm-v0"), run_id=second, claim=second_claim, holder="2@host").taken
    store.release_robot(robot=ROBOT, holder="2@host")  # (not its hold: nothing changes)
    assert store.robot_holder(robot=ROBOT) == first
    store.release_robot(robot=ROBOT, holder="1@host")
    assert store.take_robot(robot=ROBOT, run_id=second, claim=second_claim, holder="2@host").taken
    assert not store.may_move_robot(robot=ROBOT, holder="1@host").allowed


def test_a_hold_not_renewed_in_time_lapses_and_its_old_holder_may_not_move(store: Store) -> None:
    first, first_claim = claimed_run(store, "first")
    second, second_claim = claimed_run(store, "second")
    assert store.take_robot(robot=ROBOT, run_id=first, claim=first_claim, holder="1@host").taken
    age_hold(store, MOVE_WITHIN_SECONDS + 0.5)
    assert not store.may_move_robot(robot=ROBOT, holder="1@host").allowed  # too old to move on, still not free
    assert not store.take_robot(robot=ROBOT, run_id=second, claim=second_claim, holder="2@host").taken
    assert store.renew_robot(robot=ROBOT, holder="1@host")
    assert store.may_move_robot(robot=ROBOT, holder="1@host").allowed
    age_hold(store, HOLD_LAPSES_SECONDS + 0.5)
    assert store.take_robot(robot=ROBOT, run_id=second, claim=second_claim, holder="2@host").taken
    assert not store.renew_robot(robot=ROBOT, holder="1@host")
    assert not store.may_move_robot(robot=ROBOT, holder="1@host").allowed


def test_an_actor_of_a_claim_taken_over_can_neither_renew_nor_take(store: Store) -> None:
    run_id, claim = claimed_run(store, "a")
    assert store.take_robot(robot=ROBOT, run_id=run_id, claim=claim, holder="old@host").taken
    with store.writing() as session:
        session.execute(update(Run).where(Run.id == run_id).values(heartbeat_at=store._db_now(120)))
    new_claim = store.claim_next_run(worker="learner-b").claim
    assert not store.may_move_robot(robot=ROBOT, holder="old@host").allowed
    assert not store.renew_robot(robot=ROBOT, holder="old@host")
    assert store.take_robot(robot=ROBOT, run_id=run_id, claim=claim, holder="old@host").stale_claim
    # the new learner's actor waits until the old actor's hold lapses: it may still be finishing its last move
    assert store.take_robot(robot=ROBOT, run_id=run_id, claim=new_claim, holder="new@host").busy_with == run_id
    age_hold(store, HOLD_LAPSES_SECONDS + 0.5)
    assert store.take_robot(robot=ROBOT, run_id=run_id, claim=new_claim, holder="new@host").taken


def test_racing_takes_leave_one_holder(store: Store) -> None:
    holders = 8
    run_id, claim = claimed_run(store, "a")
    results: list[bool] = []
    barrier = threading.Barrier(holders)

    def take(index: int) -> None:
        barrier.wait()
        results.append(store.take_robot(robot=ROBOT, run_id=run_id, claim=claim, holder=f"{index}@host").taken)

    threads = [threading.Thread(target=take, args=(index,)) for index in range(holders)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=10)
    assert results.count(True) == 1


def test_a_robot_process_replaced_by_another_can_neither_renew_nor_move_nor_take(store: Store) -> None:
    """A robot process paused past its row's liveness, its row taken by a new process: continued, its hold (still
    its own row in robot_holds, renewed lately) no longer renews and allows no move, so it lets go rather than
    holding the arm another process now serves."""
    run_id, claim = claimed_run(store, "a")
    env_id = "robot.standin:PusherStandIn-v0"
    store.report_robot_process(robot=ROBOT, env_id=env_id, holder="1@robotpc", state="driving run 1")
    assert store.take_robot(robot=ROBOT, run_id=run_id, claim=claim, holder="1@robotpc").taken
    assert store.renew_robot(robot=ROBOT, holder="1@robotpc")
    assert store.may_move_robot(robot=ROBOT, holder="1@robotpc").allowed
    with store.writing() as session:  # the paused process's row, as a successor takes it once it is stale
        session.execute(update(RobotProcess).values(holder="2@robotpc3"))
    assert not store.renew_robot(robot=ROBOT, holder="1@robotpc")
    assert not store.may_move_robot(robot=ROBOT, holder="1@robotpc").held
    assert not store.take_robot(robot=ROBOT, run_id=run_id, claim=claim, holder="1@robotpc").taken
    store.release_robot(robot=ROBOT, holder="1@robotpc")
    assert store.take_robot(robot=ROBOT, run_id=run_id, claim=claim, holder="2@robotpc3").taken  # the successor's
