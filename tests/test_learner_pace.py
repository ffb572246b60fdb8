"""Whether a real-time run's learner keeps up with its robot: the runner records SAC updates per robot step at each
log interval, and contract.learner_pace judges them. The judgement is driven with recorded figures (the paper's
84 px and 32 filters on a 2-core CPU gave 0.6 updates a robot step at 5 Hz; on a busy machine 0.2-4 updates a
second); the API reads it from a stored run."""

import threading
import time

from conftest import create_run, learn_once_beside
from fastapi.testclient import TestClient
from test_learner_run import tiny_config

from contract.config import TrainConfig, robot_preset_for
from contract.learner_pace import (
    BEHIND_SECONDS,
    PACE_METRIC,
    SPEED_METRIC,
    PaceSample,
    learner_pace,
    pace_samples,
)
from contract.settings import Settings
from contract.store import RunStatus, Store
from learner.checkpoint import checkpoint_path, load_checkpoint

STANDIN = "robot.standin:PusherStandIn-v0"
HZ = 5.0
INTERVAL = 250  # log_every: 50 s at 5 Hz


def _config(preset: str = "real_robot", **overrides: object) -> dict:
    return getattr(TrainConfig, preset)(env_id=STANDIN, **overrides).to_dict()


def _at_5_hz(values: list[float], first_step: int = 1250) -> list[PaceSample]:
    """Figures recorded every INTERVAL steps, the robot at 5 Hz, as run_pace reads them from the store."""
    steps = [first_step + i * INTERVAL for i in range(len(values))]
    speed = [(first_step - INTERVAL, HZ)] + [(step, HZ) for step in steps]
    return pace_samples(list(zip(steps, values, strict=True)), speed)


def test_the_papers_networks_on_a_2_core_cpu_cannot_keep_up_and_the_cpu_preset_is_suggested() -> None:
    samples = _at_5_hz([0.6, 0.6])
    assert [sample.seconds for sample in samples] == [50.0, 50.0]
    pace = learner_pace(_config(), samples)
    assert pace is not None and pace.behind and pace.behind_seconds == 100.0
    assert pace.cause == "84 px and 32 filters on this CPU give 0.6 updates a robot step"
    assert pace.cause in pace.message and "cannot keep up" in pace.message and "100 s" in pace.message
    cpu = robot_preset_for("cpu")
    assert pace.suggested_fields == {"image_size": cpu.fields["image_size"], "conv_filters": cpu.fields["conv_filters"]}
    assert "TrainConfig.cpu_robot(): image_size 48, conv_filters 8" in pace.suggestion
    assert "goal set of 48 px" in pace.suggestion


def test_a_minute_below_half_is_needed_and_the_latest_interval_counts() -> None:
    one_interval = learner_pace(_config(), _at_5_hz([1.8, 0.6]))  # 50 s below half: not yet a minute
    assert one_interval is not None and not one_interval.behind and one_interval.behind_seconds == 50.0
    assert one_interval.message == "" and one_interval.suggested_fields == {}
    recovered = learner_pace(_config(), _at_5_hz([0.6, 0.6, 0.6, 1.2]))  # at half again: keeps up
    assert recovered is not None and not recovered.behind and recovered.behind_seconds == 0.0
    assert recovered.updates_per_robot_step == 1.2 and recovered.updates_per_step == 2
    assert learner_pace(_config(), []) is None  # a run in lockstep, or in its warm-up, records none


def test_a_busy_machine_between_02_and_4_updates_a_second_is_behind_while_it_is_slow() -> None:
    per_step = [2.0, 4 / HZ, 0.2 / HZ, 1.5 / HZ]  # keeping up, then 4, 0.2 and 1.5 updates a second at 5 Hz
    pace = learner_pace(_config(), _at_5_hz(per_step))
    assert pace is not None and pace.behind and pace.behind_seconds == 3 * 50.0 >= BEHIND_SECONDS
    assert pace.cause == "84 px and 32 filters on this CPU give 0.3 updates a robot step"


def test_the_cpu_preset_behind_is_told_to_find_a_faster_learner_and_a_gpu_is_named() -> None:
    cpu = learner_pace(_config("cpu_robot"), _at_5_hz([0.4, 0.5]))
    assert cpu is not None and cpu.behind and cpu.suggested_fields == {}
    assert cpu.cause == "48 px and 8 filters on this CPU give 0.5 updates a robot step"
    assert "GPU learner (device cuda)" in cpu.suggestion and "updates_per_step (now 4)" in cpu.suggestion
    gpu = learner_pace(_config(device="cuda"), _at_5_hz([0.2, 0.2]))
    assert gpu is not None and gpu.cause == "84 px and 32 filters on this GPU (cuda) give 0.2 updates a robot step"


def test_a_real_time_run_records_its_updates_per_robot_step(dot_reach: tuple[Settings, Store, int]) -> None:
    settings, store, goal_set_id = dot_reach
    config = tiny_config(total_steps=200, query_budget=3, control_hz=40.0, updates_per_step=2, policy_sync_seconds=0.2)
    run_id = create_run(store, goal_set_id, config)

    def oracle(done: threading.Event) -> None:
        while not done.is_set():
            for query in store.pending_queries(run_id=run_id):
                store.answer_query(query_id=query.id, success=bool(query.ground_truth_success), labeler="oracle")
            time.sleep(0.02)

    assert learn_once_beside(settings, oracle) == 0
    assert store.get_run(run_id=run_id).status == RunStatus.FINISHED
    recorded = [(m.step, m.value) for m in store.metrics(run_id=run_id, names=[PACE_METRIC])]
    every = config.log_every
    assert [step for step, _value in recorded] == list(range(every, config.total_steps + 1, every))
    # the figures times each interval's steps after the warm-up are every update the learner made, never more
    # than were due by then (a slow interval's updates may be made up in the next)
    previous, made = 0, 0.0
    for step, value in recorded:
        assert value >= 0
        made += value * (step - max(previous, config.initial_random_steps - 1))
        assert made <= (step - config.initial_random_steps + 1) * config.updates_per_step + 1e-6, recorded
        previous = step
    state = load_checkpoint(checkpoint_path(settings.checkpoint_dir, run_id))
    assert state is not None and abs(made - state["total_updates"]) < 1e-6 * state["total_updates"] + 1e-6


def test_the_api_says_a_stored_run_cannot_keep_up(client: TestClient, store: Store) -> None:
    def stored(config: dict, figures: list[float]) -> int:
        run_id = store.create_run(env_id=STANDIN, algorithm="vice_raq", config=config, total_steps=15_000).id
        store.record_metrics(run_id=run_id, step=1000, values={SPEED_METRIC: HZ})
        for index, figure in enumerate(figures):
            step = 1000 + (index + 1) * INTERVAL
            store.record_metrics(run_id=run_id, step=step, values={SPEED_METRIC: HZ, PACE_METRIC: figure})
        return run_id

    behind = client.get(f"/api/runs/{stored(_config(), [0.6, 0.6, 0.6])}").json()["learner_pace"]
    assert behind["behind"] and behind["behind_seconds"] == 150.0
    assert behind["cause"] == "84 px and 32 filters on this CPU give 0.6 updates a robot step"
    assert behind["suggested_fields"] == {"image_size": 48, "conv_filters": 8}
    keeping_up = client.get(f"/api/runs/{stored(_config('cpu_robot'), [2.0, 1.9])}").json()["learner_pace"]
    assert not keeping_up["behind"] and keeping_up["updates_per_robot_step"] == 1.9 and keeping_up["message"] == ""
    lockstep = store.create_run(env_id="VisualPusher-v0", algorithm="vice_raq", config={}, total_steps=5000).id
    store.record_metrics(run_id=lockstep, step=250, values={SPEED_METRIC: 30.0})
    assert client.get(f"/api/runs/{lockstep}").json()["learner_pace"] is None
