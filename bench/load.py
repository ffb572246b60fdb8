"""Load benchmark: N learners and 50 labelling clients over one database, for a bounded time, on 127.0.0.1.

    python bench/load.py                                   # PostgreSQL (started here), then SQLite
    python bench/load.py --backend postgres --learners 4 --clients 50 --duration 30
    python bench/load.py --backend sqlite                  # the learners on one host, one SQLite file

For each backend it starts the database (PostgreSQL: a throw-away server on a free port; SQLite: a file), `raq
serve` (uvicorn, one process), N learner processes (`python -m learner.worker`, at nice 10, each with its own data
dir on PostgreSQL, one shared data dir on SQLite) training small DotReach runs that post a query every 25 steps, and
50 labelling clients (threads spread over a few processes) that each list the pending queries, answer one with its
ground truth through the REST API, and think `--think` seconds (2 on average: a fast person). The runs start with
`--seed-queries` pending queries each so the clients have work from the first second. After `--duration` seconds the
clients stop, the learners are stopped with SIGTERM (they checkpoint and requeue) and every answer acknowledged with
200 is checked against the database.

Prints, per backend: requests/s, p50 / p99 answer latency (the POST …/answer round trip seen by the client),
p99 of all requests, errors (transport errors, 5xx, any status but 200 — a 409 too), lost answers
(acknowledged but not stored as given), answers the learners read, and a SUMMARY json line.
Targets: p99 <= 50 ms, 0 errors, 0 lost.
"""

import argparse
import gc
import json
import multiprocessing as mp
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from typing import NamedTuple

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from app.migrate import upgrade  # noqa: E402
from bench.processes import stop_all  # noqa: E402
from contract.config import TrainConfig  # noqa: E402
from contract.envs import encode_png  # noqa: E402
from contract.store import INT32_MAX, QueryStatus, RunStatus, Store  # noqa: E402
from learner import testing_envs  # noqa: E402
from tests.pg_server import PostgresServer  # noqa: E402

ENV = "learner.testing_envs:DotReach-v0"


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


# ---------------------------------------------------------------- the database
@contextmanager
def postgres_server() -> Iterator[str]:
    """A throw-away PostgreSQL (Debian's package, by tests/pg_server.py) on 127.0.0.1, with room for every
    connection and fsync on as in production (the last -c of a setting wins over the helper's fsync=off)."""
    with PostgresServer.started(extra_options="-c max_connections=200 -c fsync=on") as server:
        yield server.url


def run_config(seed: int) -> TrainConfig:
    """A small run that asks often and keeps going for the whole benchmark."""
    return TrainConfig(
        env_id=ENV, image_size=16, conv_filters=4, hidden_dim=32, batch_size=16, classifier_batch_size=8,
        total_steps=1_000_000, episode_steps=25, initial_random_steps=50, epoch_steps=50, classifier_steps=2,
        query_every=25, query_budget=100_000, eval_every=1_000_000, eval_episodes=1, checkpoint_every=2000,
        log_every=100, display_size=32, rollout_size=16, replay_capacity=5000, heartbeat_seconds=1.0,
        query_candidates=4, seed=seed,
    )  # fmt: skip


def prepare(url: str, learners: int, seed_queries: int) -> list[int]:
    """Goal set, one run per learner, `seed_queries` pending queries per run (with ground truth)."""
    upgrade(url)
    store = Store(url)
    goal_set_id = testing_envs.add_dot_goals(store, name="load")
    env = testing_envs.DotReach(obs_size=16, render_size=32)  # draws the pending queries' images
    run_ids = []
    rng = np.random.default_rng(0)
    for i in range(learners):
        config = run_config(seed=i)
        run_ids.append(
            store.create_run(
                env_id=ENV, algorithm="vice_raq", config=config.to_dict(), seed=i, goal_set_id=goal_set_id,
                total_steps=config.total_steps, name=f"load {i}",
            ).id
        )  # fmt: skip
        for _ in range(seed_queries):
            env.position = rng.uniform(-0.9, 0.9, size=2).astype(np.float32)
            truth = float(env._info()["success"])
            store.post_query(
                run_id=run_ids[-1], env_step=0, model_png=encode_png(env._draw(16)),
                display_png=encode_png(env._draw(32)), score=0.0, ground_truth_success=truth,
            )  # fmt: skip
    store.dispose()
    return run_ids


# ---------------------------------------------------------------- processes
def start_server(url: str, data_dir: Path, log: Path, workers: int = 1) -> tuple[subprocess.Popen, str]:
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAQ_")}
    env.update(RAQ_DATABASE_URL=url, RAQ_DATA_DIR=str(data_dir), PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
    process = subprocess.Popen(
        [sys.executable, "-m", "uvicorn", "--factory", "app.main:create_app", "--host", "127.0.0.1",
         "--port", str(port), "--log-level", "warning", "--workers", str(workers)],
        cwd=data_dir, env=env, stdout=log.open("wb"), stderr=subprocess.STDOUT,
    )  # fmt: skip
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 90
    while True:
        if process.poll() is not None:
            raise SystemExit(f"the server exited: {log.read_text()[-2000:]}")
        try:
            if httpx.get(f"{base}/health", timeout=2).status_code == 200:
                return process, base
        except httpx.HTTPError:
            pass
        if time.monotonic() > deadline:
            raise SystemExit("the server did not answer /health in 90 s")
        time.sleep(0.2)


def start_learner(url: str, data_dir: Path, name: str, nice: int) -> subprocess.Popen:
    data_dir.mkdir(parents=True, exist_ok=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAQ_")}
    env.update(
        RAQ_DATABASE_URL=url, RAQ_DATA_DIR=str(data_dir), RAQ_ENV_MODULES="learner.testing_envs",
        OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT),
    )  # fmt: skip
    log = (data_dir / f"{name}.log").open("wb")
    command = [sys.executable, "-m", "learner.worker", "--name", name, "--poll", "0.5"]
    return subprocess.Popen(
        command, cwd=data_dir, env=env, stdout=log, stderr=subprocess.STDOUT, preexec_fn=lambda: os.nice(nice)
    )


# ---------------------------------------------------------------- labelling clients
class Record(NamedTuple):
    """One request a client made."""

    kind: str  # "list" or "answer"
    seconds: float  # the round trip seen by the client
    status: int | str  # HTTP status, or "error <transport error>"
    query_id: int | None  # answers: the query answered, and the answer given
    answer: bool | None
    sent_at: float  # time.time() when sent


def _client(http: httpx.Client, index: int, deadline: float, think: float, records: list[Record]) -> None:
    rng = random.Random(index)
    time.sleep(think * rng.uniform(0, 1))  # people do not all click in the same millisecond: start spread out
    with http:
        while time.time() < deadline:
            started, at = time.perf_counter(), time.time()
            try:
                response = http.get("/api/queries", params={"status": "pending", "limit": 20})
                records.append(Record("list", time.perf_counter() - started, response.status_code, None, None, at))
                pending = response.json() if response.status_code == 200 else []
            except httpx.HTTPError as error:
                status = f"error {type(error).__name__}"
                records.append(Record("list", time.perf_counter() - started, status, None, None, at))
                pending = []
            if pending:
                query = rng.choice(pending)
                success = (query.get("ground_truth_success") or 0.0) >= 0.5
                started, at = time.perf_counter(), time.time()
                try:
                    response = http.post(
                        f"/api/queries/{query['id']}/answer", json={"success": success, "labeler": f"client-{index}"}
                    )
                    status: int | str = response.status_code
                except httpx.HTTPError as error:
                    status = f"error {type(error).__name__}"
                records.append(Record("answer", time.perf_counter() - started, status, query["id"], success, at))
            time.sleep(think * rng.uniform(0.5, 1.5))


def _client_process(
    base: str, indices: list[int], duration: float, think: float, out: mp.Queue, ready: mp.Queue, go: mp.Event
) -> None:
    clients = [httpx.Client(base_url=base, timeout=10) for _ in indices]  # made before the clock starts
    gc.collect()
    gc.freeze()  # a full collection of this process would stall its clients and count as server latency
    ready.put(os.getpid())
    go.wait()
    deadline = time.time() + duration
    records: list[Record] = []
    threads = [
        threading.Thread(target=_client, args=(http, i, deadline, think, records))
        for http, i in zip(clients, indices, strict=True)
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    out.put(records)


def warm_up(base: str, clients: int) -> None:
    """The server's first requests build its routes' validators, compile the store's SQL and open its pooled
    database connections (PostgreSQL: a backend process each): seconds on a loaded machine, once per server
    process. Make them, from as many clients at once as will label, before the measured clients start. Stores
    nothing (the answer goes to a query that does not exist)."""

    def visit(_: int) -> None:
        with httpx.Client(base_url=base, timeout=60) as http:
            http.get("/api/queries", params={"status": "pending", "limit": 20}).raise_for_status()
            http.get("/api/queries/next").raise_for_status()
            response = http.post(f"/api/queries/{INT32_MAX}/answer", json={"success": True, "labeler": "warm-up"})
            assert response.status_code == 404, response.text

    with ThreadPoolExecutor(max_workers=clients) as pool:
        list(pool.map(visit, range(clients)))


def label(base: str, clients: int, processes: int, duration: float, think: float) -> list[Record]:
    """The requests the clients made in `duration` seconds (each finishes the request under way at the end)."""
    context = mp.get_context("spawn")
    out: mp.Queue = context.Queue()
    ready: mp.Queue = context.Queue()
    go = context.Event()
    groups = [list(range(clients))[i::processes] for i in range(processes)]
    workers = [
        context.Process(target=_client_process, args=(base, group, duration, think, out, ready, go))
        for group in groups
        if group
    ]
    for worker in workers:
        worker.start()
    for _ in workers:  # the clients' processes have started (spawn imports take seconds on a loaded machine)
        ready.get(timeout=300)
    go.set()
    records = [record for _ in workers for record in out.get(timeout=duration + 120)]
    for worker in workers:
        worker.join(timeout=30)
    return records


# ---------------------------------------------------------------- one backend
def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q) * 1000) if values else float("nan")


def slowest(answers: list[Record], records: list[Record], share: float = 0.01) -> list[list[float]]:
    """The slowest 1% of answers as [seconds into the labelling, ms]: a burst or a steady tail."""
    if not answers:
        return []
    start = min(r.sent_at for r in records)
    worst = sorted(answers, key=lambda r: r.seconds)[-max(1, round(share * len(answers))) :]
    return sorted([round(r.sent_at - start, 1), round(r.seconds * 1000)] for r in worst)


def bench(backend: str, args: argparse.Namespace) -> dict:
    base_dir = Path(tempfile.mkdtemp(prefix=f"raq-load-{backend}-"))
    with contextmanager_for(backend, base_dir, args) as url:
        run_ids = prepare(url, args.learners, args.seed_queries)
        store = Store(url)
        server, base = start_server(url, base_dir, base_dir / "server.log", args.server_workers)
        separate = backend == "postgres"  # PostgreSQL: each learner its own data dir, as on its own host
        learners = [
            start_learner(url, base_dir / (f"host-{i}" if separate else "host"), f"learner-{i}", args.learner_nice)
            for i in range(args.learners)
        ]
        try:
            deadline = time.monotonic() + 300
            while sum(store.get_run(run_id=r).status == RunStatus.TRAINING for r in run_ids) < len(run_ids):
                if time.monotonic() > deadline:
                    raise SystemExit("the learners did not all start training within 300 s")
                time.sleep(0.5)
            steps_before = sum(store.get_run(run_id=r).step for r in run_ids)
            asked_before = store.count_queries()
            warm_up(base, args.clients)
            records = label(base, args.clients, args.client_processes, args.duration, args.think)
            steps_after = sum(store.get_run(run_id=r).step for r in run_ids)
            asked = store.count_queries() - asked_before
        finally:
            stop_all(learners, signal.SIGTERM, timeout=120)
            server.terminate()
            server.wait(timeout=30)
        answers = [r for r in records if r.kind == "answer"]
        acknowledged = [r for r in answers if r.status == 200]
        errors = [r for r in records if r.status != 200]
        lost = 0
        for record in acknowledged:
            query = store.get_query(query_id=record.query_id)
            lost += query.status != QueryStatus.ANSWERED or query.answer != record.answer
        answered_ids = {r.query_id for r in acknowledged}
        read = sum(store.get_query(query_id=q).used_at is not None for q in answered_ids)
        store.dispose()
    shutil.rmtree(base_dir, ignore_errors=True)
    result = {
        "backend": backend, "learners": args.learners, "clients": args.clients, "seconds": args.duration,
        "server_workers": args.server_workers,
        "requests": len(records), "requests_per_s": round(len(records) / args.duration, 1),
        "answers": len(acknowledged), "answers_per_s": round(len(acknowledged) / args.duration, 1),
        "answer_p50_ms": round(percentile([r.seconds for r in answers], 50), 1),
        "answer_p99_ms": round(percentile([r.seconds for r in answers], 99), 1),
        "slowest_answers": slowest(answers, records),
        "all_p99_ms": round(percentile([r.seconds for r in records], 99), 1),
        "errors": len(errors), "error_kinds": sorted({str(r.status) for r in errors}), "lost": lost,
        "distinct_queries_answered": len(answered_ids), "read_by_learners": read,
        "learner_steps": steps_after - steps_before, "queries_posted_by_learners": asked,
    }  # fmt: skip
    print(
        f"{backend}: {result['requests_per_s']} requests/s ({result['answers_per_s']} answers/s), answer latency "
        f"p50 {result['answer_p50_ms']} ms p99 {result['answer_p99_ms']} ms (all requests p99 "
        f"{result['all_p99_ms']} ms), errors {result['errors']}, lost {lost}; {len(answered_ids)} queries answered, "
        f"{read} of them already read by the learners; learners: {result['learner_steps']} env steps, "
        f"{asked} queries posted",
        flush=True,
    )
    return result


@contextmanager
def contextmanager_for(backend: str, base_dir: Path, args: argparse.Namespace) -> Iterator[str]:
    if backend == "sqlite":
        yield f"sqlite:///{base_dir / 'raq.sqlite3'}"
    elif args.database_url:
        yield args.database_url
    else:
        with postgres_server() as url:
            yield url


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--backend", choices=["postgres", "sqlite", "both"], default="both")
    parser.add_argument("--database-url", default=None, help="an existing, empty PostgreSQL database to use")
    parser.add_argument("--learners", type=int, default=4)
    parser.add_argument("--clients", type=int, default=50)
    parser.add_argument(
        "--server-workers", type=int, default=1, help="server processes (`raq serve --workers`; default 1)"
    )
    parser.add_argument("--client-processes", type=int, default=5, help="processes the client threads run in")
    parser.add_argument("--duration", type=float, default=30.0, help="seconds of labelling per backend")
    parser.add_argument("--think", type=float, default=2.0, help="mean seconds a client thinks between answers")
    parser.add_argument(
        "--learner-nice", type=int, default=10,
        help="the learners' nice value: on one machine they stand in for learners on other hosts, so they must not "
        "starve the server and the clients of CPU (0: equal priority)",
    )  # fmt: skip
    parser.add_argument("--seed-queries", type=int, default=250, help="pending queries per run at the start")
    args = parser.parse_args(argv)
    if not 1 <= args.learners <= 32 or not 1 <= args.clients <= 500 or not 1 <= args.duration <= 600:
        parser.error("bounded: 1-32 learners, 1-500 clients, 1-600 s")
    if not 1 <= args.server_workers <= 4:  # each keeps up to 40 connections; the throw-away PostgreSQL allows 200
        parser.error("bounded: 1-4 server workers")
    backends = ["postgres", "sqlite"] if args.backend == "both" else [args.backend]
    results = [bench(backend, args) for backend in backends]
    print("SUMMARY " + json.dumps(results), flush=True)
    ok = all(r["answer_p99_ms"] <= 50 and r["errors"] == 0 and r["lost"] == 0 for r in results)
    print("targets (p99 <= 50 ms, 0 errors, 0 lost): " + ("met" if ok else "NOT met"), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
