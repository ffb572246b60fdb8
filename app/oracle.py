"""`raq oracle`: answer pending queries through the REST API from the simulator's ground truth.

A stand-in for a person (for benchmarks and demos): each query's `ground_truth_success` (>= 0.5 means
yes) is the answer, flipped for a `--noise` fraction of queries (seeded), after `--delay` seconds.
"""

import argparse
import random
import signal
import sys
import threading
import time
from typing import Any

import httpx

from contract.settings import get_settings

SUCCESS_THRESHOLD = 0.5
POLL_SECONDS = 1.0


def _say(message: str) -> None:
    print(f"[oracle] {message}", flush=True)


def truthful_answer(query: dict[str, Any]) -> bool | None:
    """The simulator's verdict on the query, or None when the learner stored none."""
    truth = query.get("ground_truth_success")
    if truth is None:
        return None
    return float(truth) >= SUCCESS_THRESHOLD


def answer_pending(
    client: httpx.Client,
    *,
    run_id: int | None = None,
    noise: float = 0.0,
    rng: random.Random | None = None,
    labeler: str = "oracle",
    delay: float = 0.0,
    reported: set[int] | None = None,
) -> int:
    """Answer every pending query (of `run_id`, or of all runs) once; returns how many were answered.

    Queries without ground truth stay pending (reported once per id in `reported`). A query that
    someone else answered or removed meanwhile (409 / 404) is reported and passed over.
    """
    rng = rng or random.Random()
    reported = reported if reported is not None else set()
    params: dict[str, Any] = {"status": "pending", "limit": 1000}
    if run_id is not None:
        params["run_id"] = run_id
    response = client.get("/api/queries", params=params)
    response.raise_for_status()
    answered = 0
    for query in response.json():
        truth = truthful_answer(query)
        if truth is None:
            if query["id"] not in reported:
                reported.add(query["id"])
                _say(f"query {query['id']} (run {query['run_id']}) has no ground truth: left pending for a person")
            continue
        flipped = noise > 0 and rng.random() < noise
        success = truth != flipped
        if delay > 0:
            time.sleep(delay)
        result = client.post(f"/api/queries/{query['id']}/answer", json={"success": success, "labeler": labeler})
        if result.status_code in (404, 409):
            _say(f"query {query['id']}: {result.json().get('detail', result.text)}")
            continue
        if result.status_code == 401:
            raise PermissionError("the server needs a token: pass --token or set RAQ_API_TOKEN")
        result.raise_for_status()
        answered += 1
        note = " (flipped by noise)" if flipped else ""
        _say(
            f"query {query['id']} (run {query['run_id']}, step {query['env_step']}, "
            f"ground truth {query['ground_truth_success']:.2f}): answered {'yes' if success else 'no'}{note}"
        )
    return answered


def build_parser() -> argparse.ArgumentParser:
    settings = get_settings()
    parser = argparse.ArgumentParser(
        prog="raq oracle",
        description="Answer pending queries from the simulator's ground truth, through the REST API.",
    )
    parser.add_argument("--url", default=settings.base_url, help="server base URL (default: %(default)s)")
    parser.add_argument("--run", type=int, default=None, help="only this run's queries (default: all runs)")
    parser.add_argument("--noise", type=float, default=0.0, help="fraction of answers to flip, 0..1 (default 0)")
    parser.add_argument("--delay", type=float, default=0.0, help="seconds to wait before each answer (default 0)")
    parser.add_argument("--once", action="store_true", help="answer what is pending now, then exit")
    parser.add_argument("--token", default=settings.api_token, help="API token (default: $RAQ_API_TOKEN)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the noise (default 0)")
    parser.add_argument("--labeler", default="oracle", help="name recorded with each answer (default: oracle)")
    return parser


def _stop_on_signals() -> None:
    """SIGINT and SIGTERM stop the oracle (as Ctrl-C does), also where it was started with SIGINT ignored, as a
    background job's children are: a script that started it can stop it."""

    def interrupt(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt(f"signal {signum}")

    if threading.current_thread() is threading.main_thread():  # (signal handlers can be set there only)
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, interrupt)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if not 0.0 <= args.noise <= 1.0:
        _say("--noise must be between 0 and 1")
        return 2
    if args.delay < 0:
        _say("--delay must not be negative")
        return 2
    headers = {"Authorization": f"Bearer {args.token}"} if args.token else {}
    rng = random.Random(args.seed)
    reported: set[int] = set()
    total = 0
    with httpx.Client(base_url=args.url.rstrip("/"), headers=headers, timeout=30.0) as client:
        try:  # (from the moment the handlers are set: a signal may come at once)
            if not args.once:
                scope = f"run {args.run}" if args.run is not None else "all runs"
                _stop_on_signals()
                _say(f"answering queries of {scope} at {args.url} (noise {args.noise}, delay {args.delay}s); "
                     "Ctrl-C stops")  # fmt: skip
            while True:
                try:
                    total += answer_pending(
                        client, run_id=args.run, noise=args.noise, rng=rng, labeler=args.labeler,
                        delay=args.delay, reported=reported,
                    )  # fmt: skip
                except PermissionError as error:
                    _say(str(error))
                    return 1
                except httpx.HTTPError as error:
                    _say(f"cannot talk to {args.url}: {error}")
                    if args.once:
                        return 1
                if args.once:
                    _say(f"answered {total} quer{'y' if total == 1 else 'ies'}")
                    return 0
                time.sleep(POLL_SECONDS)
        except KeyboardInterrupt:
            _say(f"stopped; answered {total} quer{'y' if total == 1 else 'ies'}")
            return 0


if __name__ == "__main__":
    sys.exit(main())
