"""Schemathesis over the whole REST API of a live server on 127.0.0.1 (with a token): no 5xx, and every status
code, content type and body is the one the OpenAPI spec documents. Bounded: a fixed seed and a few examples
per operation (about 500 cases, ~20 s); it talks only to 127.0.0.1."""

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from conftest import LiveServer, image_bytes

from contract.store import Store

TOKEN = "fuzz-token"
CHECKS = "not_a_server_error,status_code_conformance,content_type_conformance,response_schema_conformance"


def _seed(store: Store) -> None:
    """A goal set with a photo, a run with pending / answered queries, metrics, events and a rollout, so the
    fuzzer reaches the routes behind the ids 1 (and 404s beyond them)."""
    goal_set = store.create_goal_set(name="seeded")
    png = image_bytes((48, 48))
    store.add_goal_example(
        goal_set_id=goal_set.id, filename="goal.png", original=png, original_media_type="image/png",
        width=48, height=48, model_png=png, display_png=png,
    )  # fmt: skip
    run = store.create_run(env_id="VisualPusher-v0", algorithm="vice_raq", config={}, goal_set_id=goal_set.id)
    for step in range(3):
        store.post_query(run_id=run.id, env_step=1000 * step, model_png=png, display_png=png, score=0.5 - step)
    store.answer_query(query_id=2, success=True, labeler="seed")
    store.record_metrics(run_id=run.id, step=1000, values={"eval/success_rate": 0.4, "train/loss": 1.5})
    store.record_event(run_id=run.id, message="seeded")
    store.record_rollout(run_id=run.id, env_step=1000, data=b"GIF89a", frame_count=1)


@pytest.mark.slow
def test_schemathesis_finds_no_server_error_and_no_schema_violation(
    make_live_server: Callable[..., LiveServer], store: Store, tmp_path: Path
) -> None:
    _seed(store)
    server = make_live_server(RAQ_API_TOKEN=TOKEN)
    report_path = tmp_path / "schemathesis.json"
    command = [
        str(Path(sys.executable).parent / "st"), "run", f"{server.url}/openapi.json",
        "--header", f"Authorization: Bearer {TOKEN}", "--checks", CHECKS, "--max-examples", "5", "--seed", "13",
        "--workers", "1", "--request-timeout", "10", "--no-color",
        "--report", "json", "--report-json-path", str(report_path), "--report-dir", str(tmp_path),
    ]  # fmt: skip
    result = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=240, check=False)
    output = result.stdout + result.stderr
    assert report_path.exists(), output
    report = json.loads(report_path.read_text())
    cases = report["test_cases"]
    print(f"schemathesis: {cases['generated']} cases over {report['operations']['tested']} operations, "
          f"{cases['with_failures']} with failures, {report['running_time']:.1f} s")  # fmt: skip
    assert report["operations"]["tested"] == report["operations"]["total"] >= 24, output
    assert 200 <= cases["generated"] <= 2000, output  # bounded, yet every operation saw many cases
    assert report["failures"] == [] and cases["with_failures"] == 0, output
    assert report["errors"] == [] and cases["errored"] == 0, output
    assert result.returncode == 0, output
    assert "Traceback" not in server.log_path.read_text()  # no exception escaped a route
