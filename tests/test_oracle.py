"""`raq oracle` against a real uvicorn server: answers from ground truth, --noise flips, no truth stays pending."""

import io
import random
import signal
import subprocess
import sys

import httpx
import pytest
from PIL import Image

from app import oracle
from contract.store import Store


def _png(size: int) -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (size, size), (10, 120, 30)).save(buffer, format="PNG")
    return buffer.getvalue()


def _run_with_queries(store: Store, truths: list[float | None]) -> tuple[int, list[int]]:
    run = store.create_run(env_id="VisualPusher-v0", algorithm="sparse", config={}, total_steps=1000)
    ids = [
        store.post_query(
            run_id=run.id, env_step=100 * (i + 1), model_png=_png(48), display_png=_png(256), score=0.3 * i,
            ground_truth_success=truth,
        ).id
        for i, truth in enumerate(truths)
    ]  # fmt: skip
    return run.id, ids


def test_oracle_once_answers_from_ground_truth(
    live_server: str, store: Store, capsys: pytest.CaptureFixture[str]
) -> None:
    honest_run, honest = _run_with_queries(store, [1.0, 0.0, 0.7, 0.2, None])
    noisy_run, noisy = _run_with_queries(store, [1.0, 0.0, 0.9])

    assert oracle.main(["--url", live_server, "--run", str(honest_run), "--once", "--labeler", "sim-oracle"]) == 0
    answers = {query_id: store.get_query(query_id=query_id) for query_id in honest}
    assert [answers[i].answer for i in honest[:4]] == [True, False, True, False]
    assert all(answers[i].labeler == "sim-oracle" for i in honest[:4])
    assert answers[honest[4]].status == "pending"  # no ground truth: left for a person
    output = capsys.readouterr().out
    assert "no ground truth" in output and "answered 4 queries" in output
    # the other run was not touched
    assert all(store.get_query(query_id=i).status == "pending" for i in noisy)

    assert oracle.main(["--url", live_server, "--run", str(noisy_run), "--once", "--noise", "1.0", "--seed", "7"]) == 0
    assert [store.get_query(query_id=i).answer for i in noisy] == [False, True, False]
    assert "flipped by noise" in capsys.readouterr().out

    # running again changes nothing: answered queries are no longer pending
    assert oracle.main(["--url", live_server, "--once"]) == 0
    assert store.get_query(query_id=honest[4]).status == "pending"


def test_answer_pending_with_delay_and_partial_noise(live_server: str, store: Store) -> None:
    run_id, ids = _run_with_queries(store, [1.0] * 20)
    with httpx.Client(base_url=live_server) as client:
        count = oracle.answer_pending(
            client, run_id=run_id, noise=0.5, rng=random.Random(0), labeler="oracle", delay=0.01
        )
    assert count == 20
    answers = [store.get_query(query_id=i).answer for i in ids]
    flips = answers.count(False)
    expected_rng = random.Random(0)
    assert flips == sum(expected_rng.random() < 0.5 for _ in ids)  # seeded: reproducible
    assert 0 < flips < 20


def test_oracle_reports_a_server_it_cannot_reach(capsys: pytest.CaptureFixture[str]) -> None:
    assert oracle.main(["--url", "http://127.0.0.1:9", "--once"]) == 1
    assert "cannot talk to" in capsys.readouterr().out
    assert oracle.main(["--noise", "2", "--once"]) == 2


def test_oracle_stops_on_sigint_even_when_started_with_it_ignored() -> None:
    """A background job's children inherit SIGINT ignored: the oracle still stops on it (and on SIGTERM)."""
    for signum in (signal.SIGINT, signal.SIGTERM):
        process = subprocess.Popen(
            [sys.executable, "-m", "cli", "oracle", "--url", "http://127.0.0.1:9"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
        )  # fmt: skip
        assert process.stdout is not None
        assert "Ctrl-C stops" in process.stdout.readline()  # (its handlers are set by then)
        process.send_signal(signum)
        output, _ = process.communicate(timeout=20)
        assert process.returncode == 0, output
        assert "stopped; answered 0 queries" in output
