"""Hardening, one test per finding: every bad request is a clear 4xx, the learner imports only the env modules
its operator allows, a token guards reads too, and nothing reads a body it is about to refuse."""

import socket
import subprocess
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from datetime import timedelta

import httpx
import pytest
import sqlalchemy as sa
from conftest import ROOT, LiveServer, image_bytes
from fastapi.testclient import TestClient

from contract import envs
from contract.settings import Settings
from contract.store import INT64_MAX, LoginFailure, Query, Store, first_line
from contract.store.models import utcnow
from learner.worker import work

TOKEN = "hardening-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
BEYOND_INT64 = str(INT64_MAX + 1)
HUGE = "9" * 40


def _field_errors(response) -> dict[str, str]:  # type: ignore[no-untyped-def]
    assert response.status_code == 422, response.text
    return {str(item["loc"][-1]): item["msg"] for item in response.json()["detail"]}


def _run(client: TestClient, goal_set_id: int, **body: object) -> dict:
    response = client.post("/api/runs", json={"env_id": "VisualPusher-v0", "goal_set_id": goal_set_id, **body})
    assert response.status_code == 201, response.text
    return response.json()


# ---------------------------------------------------------------- 1. no 5xx from any integer
def test_integers_beyond_their_column_are_4xx_and_keep_the_connection(
    live_server: str, store: Store, make_image: Callable[..., bytes]
) -> None:
    """Were: OverflowError from SQLite (500) for ids, run_id, since_id, seed, total_steps; uvicorn then
    dropped the keep-alive connection."""
    goal_set = store.create_goal_set(name="g")
    png = make_image()
    store.add_goal_example(
        goal_set_id=goal_set.id, filename="g.png", original=png, original_media_type="image/png", width=96,
        height=64, model_png=png, display_png=png,
    )  # fmt: skip
    run = store.create_run(env_id="VisualPusher-v0", algorithm="vice_raq", config={}, goal_set_id=goal_set.id)
    with httpx_client(live_server) as client:
        requests = [
            ("GET", f"/api/runs/{BEYOND_INT64}", None),
            ("GET", f"/api/runs/{HUGE}/metrics", None),
            ("GET", f"/api/runs/{run.id}/events?since_id={BEYOND_INT64}", None),
            ("GET", f"/api/runs/{run.id}/metrics?since_step={HUGE}", None),
            ("GET", f"/api/runs/-{HUGE}/rollout/latest", None),
            ("POST", f"/api/runs/{BEYOND_INT64}/stop", None),
            ("GET", f"/api/goal-sets/{BEYOND_INT64}", None),
            ("DELETE", f"/api/goal-sets/{HUGE}", None),
            ("GET", f"/api/goal-examples/{BEYOND_INT64}/image", None),
            ("GET", f"/api/queries?run_id={BEYOND_INT64}", None),
            ("GET", f"/api/queries/next?run_id={HUGE}", None),
            ("GET", f"/api/queries/{BEYOND_INT64}", None),
            ("POST", f"/api/queries/{BEYOND_INT64}/answer", {"success": True}),
            ("POST", "/api/runs", {"env_id": "VisualPusher-v0", "goal_set_id": goal_set.id, "seed": INT64_MAX + 1}),
            ("POST", "/api/runs", {"env_id": "VisualPusher-v0", "goal_set_id": goal_set.id, "seed": -1}),
            ("POST", "/api/runs", {"goal_set_id": INT64_MAX + 1}),
            ("POST", "/api/runs", {"goal_set_id": goal_set.id, "config": {"total_steps": 10**30}}),
            ("GET", f"/runs/{BEYOND_INT64}", None),
            ("GET", f"/queue?run={HUGE}", None),
            ("GET", f"/goal-sets/{BEYOND_INT64}", None),
        ]
        for method, url, body in requests:
            response = client.request(method, url, json=body)
            assert 400 <= response.status_code < 500, (method, url, response.status_code, response.text)
            assert response.headers.get("connection", "").lower() != "close", (method, url)
        assert client.get("/health").status_code == 200
    assert store.count_runs() == 1  # nothing was created on the way


def httpx_client(base_url: str) -> httpx.Client:
    return httpx.Client(base_url=base_url, timeout=30)


def test_openapi_documents_the_status_codes_routes_return(client: TestClient) -> None:
    """Were: 404, 409 and 400 returned but not in the spec (schemathesis: test_fuzz.py runs over all of it)."""
    paths = client.get("/openapi.json").json()["paths"]
    assert {"200", "401", "403", "404", "409", "422"} <= set(
        paths["/api/queries/{query_id}/answer"]["post"]["responses"]
    )
    assert {"201", "400", "401", "404", "413", "422"} <= set(
        paths["/api/goal-sets/{goal_set_id}/examples"]["post"]["responses"]
    )
    assert {"201", "400", "409"} <= set(paths["/api/goal-sets"]["post"]["responses"])
    assert {"200", "401", "404", "422"} <= set(paths["/api/runs/{run_id}"]["get"]["responses"])
    run_id = paths["/api/runs/{run_id}"]["get"]["parameters"][0]["schema"]
    assert (run_id["minimum"], run_id["maximum"]) == (1, 2**31 - 1)


# ---------------------------------------------------------------- run configs
def test_non_finite_and_unbounded_configs_are_422_naming_the_field(
    client: TestClient, goal_set_with_photo: dict
) -> None:
    base = {"env_id": "VisualPusher-v0", "goal_set_id": goal_set_with_photo["id"]}
    cases = {
        "actor_lr": "Infinity", "critic_lr": "NaN", "tau": "-Infinity",
        "total_steps": 10**12, "replay_capacity": 10**9, "batch_size": 10**7, "display_size": 10**5,
        "device": "cuda:99", "heartbeat_seconds": 1e9, "query_candidates": 10**6,
    }  # fmt: skip
    for field, value in cases.items():
        errors = _field_errors(client.post("/api/runs", json={**base, "config": {field: value}}))
        assert field in errors, (field, errors)
    # Python's json and JSON5-ish clients send bare Infinity / NaN literals: refused the same way
    raw = b'{"env_id": "VisualPusher-v0", "goal_set_id": %d, "config": {"actor_lr": Infinity}}' % base["goal_set_id"]
    errors = _field_errors(client.post("/api/runs", content=raw, headers={"Content-Type": "application/json"}))
    assert "actor_lr" in errors
    # the same literals anywhere in any body: 422 (FastAPI's own 422 could not encode them and answered 500)
    for path, body in [
        ("/api/runs", b'{"seed": Infinity}'),
        ("/api/goal-sets", b'{"name": "n", "image_size": -Infinity}'),
        ("/api/queries/1/answer", b'{"success": NaN}'),
    ]:
        response = client.post(path, content=body, headers={"Content-Type": "application/json"})
        assert response.status_code == 422, (path, response.text)
    # seed -1 used to pass and fail in the learner
    errors = _field_errors(client.post("/api/runs", json={**base, "seed": -1}))
    assert "between 0 and 2147483647" in errors["seed"]
    # a device string that is not one (which GPUs a run may name is the learners' business:
    # tests/test_learner_capabilities.py)
    errors = _field_errors(client.post("/api/runs", json={**base, "config": {"device": "cuda:16"}}))
    assert "must be 'cpu', 'cuda' or 'cuda:N'" in errors["device"]
    assert client.get("/api/runs").json() == []


def test_replay_memory_is_checked_against_this_hosts_ram(client: TestClient, goal_set_with_photo: dict) -> None:
    base = {"env_id": "VisualPusher-v0", "goal_set_id": goal_set_with_photo["id"]}
    # 5M transitions of 256x256 frames (a run takes its image size from its goal set): about 1.8 TiB, more than
    # any host this runs on
    big = client.post("/api/goal-sets", json={"name": "256 px", "image_size": 256}).json()
    errors = _field_errors(
        client.post("/api/runs", json={**base, "goal_set_id": big["id"], "config": {"replay_capacity": 5_000_000}})
    )
    assert "GiB" in errors["replay_capacity"] and "of its RAM" in errors["replay_capacity"]
    # the defaults fit (about 2.8 GiB)
    _run(client, goal_set_with_photo["id"])


def test_unknown_fields_at_any_level_are_422_naming_them(client: TestClient, goal_set_with_photo: dict) -> None:
    """Were: unknown top-level fields silently dropped."""
    base = {"env_id": "VisualPusher-v0", "goal_set_id": goal_set_with_photo["id"]}
    response = client.post("/api/runs", json={**base, "totl_steps": 5})
    assert response.status_code == 422 and response.json()["detail"][0]["loc"] == ["body", "totl_steps"]
    assert _field_errors(client.post("/api/runs", json={**base, "config": {"totl_steps": 5}})) == {
        "totl_steps": "totl_steps: unknown config field"
    }
    assert _field_errors(client.post("/api/goal-sets", json={"name": "x", "colour": "red"})) == {
        "colour": "Extra inputs are not permitted"
    }
    assert "whom" in _field_errors(client.post("/api/queries/1/answer", json={"success": True, "whom": "me"}))
    assert "why" in _field_errors(client.post("/api/queries/1/skip", json={"why": "unsure"}))
    assert client.get("/api/runs").json() == [] and client.get("/api/goal-sets").json() != []


def test_text_no_database_can_store_is_422(client: TestClient) -> None:
    for body in [rb'{"name": "half \ud800 a pair"}', rb'{"name": "nul \u0000"}']:
        response = client.post("/api/goal-sets", content=body, headers={"Content-Type": "application/json"})
        assert response.status_code == 422, (body, response.text)
    assert client.get("/api/goal-sets").json() == []


# ---------------------------------------------------------------- 2. env ids
def test_env_ids_must_be_registered_or_from_an_allowed_module(
    make_client: Callable[..., TestClient], goal_set_with_photo: dict
) -> None:
    client = make_client(env_modules=("learner.testing_envs",))
    goal_set_id = goal_set_with_photo["id"]
    # any installed module, named by whoever can create a run: refused, nothing imported
    for env_id in ["os:system", "subprocess:Popen", "this:Zen-v0", "learner.testing_envs:DotReach-v0:x"]:
        errors = _field_errors(client.post("/api/runs", json={"env_id": env_id, "goal_set_id": goal_set_id}))
        assert "env_id" in errors, env_id
    assert (
        "RAQ_ENV_MODULES lists: learner.testing_envs"
        in _field_errors(client.post("/api/runs", json={"env_id": "os:system", "goal_set_id": goal_set_id}))["env_id"]
    )
    # a near miss is refused at once, with suggestions
    errors = _field_errors(client.post("/api/runs", json={"env_id": "VisualPusher-v1", "goal_set_id": goal_set_id}))
    assert "not a registered gymnasium id" in errors["env_id"] and "'VisualPusher-v0'" in errors["env_id"]
    errors = _field_errors(client.post("/api/runs", json={"env_id": "VisualDor-v0", "goal_set_id": goal_set_id}))
    assert "'VisualDoor-v0'" in errors["env_id"]
    errors = _field_errors(
        client.post("/api/runs", json={"env_id": "learner.testing_env:DotReach-v0", "goal_set_id": goal_set_id})
    )
    assert "'learner.testing_envs:DotReach-v0'" in errors["env_id"]
    # registered image envs and allowed modules (and their submodules) pass; CartPole-v1 (no images): see
    # tests/test_bad_observations.py
    for env_id in ["VisualDoor-v0", "learner.testing_envs:DotReach-v0", "sim:VisualPicker-v0"]:
        _run(client, goal_set_id, env_id=env_id)
    assert "this" not in sys.modules
    # without RAQ_ENV_MODULES only registered ids (and the project's own sim) pass
    plain = make_client(env_modules=())
    errors = _field_errors(plain.post("/api/runs", json={"env_id": "learner.testing_envs:DotReach-v0",
                                                           "goal_set_id": goal_set_id}))  # fmt: skip
    assert "RAQ_ENV_MODULES lists: none" in errors["env_id"]


def test_the_learner_never_imports_a_module_that_is_not_allowed(
    make_settings: Callable[..., Settings], store: Store
) -> None:
    """A run written straight into the database (not through the API) still cannot make the learner import."""
    assert envs.allowed_env_modules() == ("learner.testing_envs",)  # what conftest sets for the tests' learners
    with pytest.raises(envs.EnvNotAllowed, match="RAQ_ENV_MODULES"):
        envs.make_env("this:Zen-v0", image_size=16, display_size=32)
    with pytest.raises(envs.EnvNotAllowed):
        envs.make_env("learner.testing_envs:this:Zen-v0", image_size=16, display_size=32)
    run = store.create_run(env_id="this:Zen-v0", algorithm="sparse", config={"env_id": "this:Zen-v0"})
    assert work(make_settings(), worker_name="w", once=True) == 1
    failed = store.get_run(run_id=run.id)
    assert failed.status == "failed" and "not in RAQ_ENV_MODULES" in failed.status_reason
    assert "this" not in sys.modules  # `import this` would have printed the Zen of Python
    env = envs.make_env("learner.testing_envs:DotReach-v0", image_size=16, display_size=32)
    env.close()


# ---------------------------------------------------------------- 3. request bodies
def test_json_bodies_are_capped_before_they_are_read(make_client: Callable[..., TestClient]) -> None:
    client = make_client(max_json_bytes=4096)
    big = b'{"name": "' + b"x" * 10_000 + b'"}'
    response = client.post("/api/goal-sets", content=big, headers={"Content-Type": "application/json"})
    assert response.status_code == 413 and "4,096" in response.json()["detail"]

    def chunks():  # no Content-Length: counted as it arrives
        yield b'{"name": "'
        for _ in range(10):
            yield b"x" * 1000
        yield b'"}'

    response = client.post("/api/goal-sets", content=chunks(), headers={"Content-Type": "application/json"})
    assert response.status_code == 413
    assert client.post("/api/goal-sets", json={"name": "small"}).status_code == 201


def _send_head(url: str, head: str, first_bytes: bytes) -> socket.socket:
    host, port = url.removeprefix("http://").split(":")
    sock = socket.create_connection((host, int(port)), timeout=10)
    sock.sendall(head.encode() + first_bytes)
    return sock


def _response_status(sock: socket.socket) -> int:
    data = b""
    while b"\r\n" not in data:
        chunk = sock.recv(4096)
        if not chunk:
            break
        data += chunk
    return int(data.split(b" ", 2)[1])


def test_with_a_token_a_request_without_it_is_refused_before_its_body(
    make_live_server: Callable[..., LiveServer],
) -> None:
    """Were: the whole body read (and multipart spooled to disk) before the token was checked."""
    server = make_live_server(RAQ_API_TOKEN=TOKEN)
    for path, content_type in [
        ("/api/goal-sets", "application/json"),
        ("/api/goal-sets/1/examples", "multipart/form-data; boundary=xyz"),
    ]:
        head = (
            f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: {content_type}\r\n"
            f"Content-Length: {200 * 1024 * 1024}\r\n\r\n"
        )
        started = time.monotonic()
        sock = _send_head(server.url, head, b"x" * 1024)  # 1 KiB of the announced 200 MiB, then wait
        with sock:
            assert _response_status(sock) == 401
        assert time.monotonic() - started < 5  # answered without waiting for the body


@pytest.mark.slow
def test_memory_stays_flat_under_a_flood_of_large_unauthenticated_requests(
    make_live_server: Callable[..., LiveServer],
) -> None:
    """Were: a 200 MB JSON body without the token took the server from 90 to 700 MB. Now: 36 requests, each
    announcing 200-300 MB and sending up to 8 MiB of it (as much as the server takes before it hangs up), to
    127.0.0.1 only, in a few seconds; the server's RSS may not grow by more than 25 MB."""
    server = make_live_server(RAQ_API_TOKEN=TOKEN, RAQ_MAX_JSON_BYTES="1048576")
    with httpx_client(server.url) as client:  # warm up the routes and the store once
        for _ in range(3):
            client.post("/api/goal-sets", json={"name": "x"})
            client.get("/api/runs")
    time.sleep(0.5)
    before = server.rss_bytes()
    statuses: list[int] = []
    chunk = b"{" + b"x" * (1024 * 1024 - 1)
    started = time.monotonic()
    for index in range(36):
        kind = index % 3
        if kind == 0:
            head = "POST /api/runs HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            head += f"Content-Length: {200 * 1024 * 1024}\r\n\r\n"
        elif kind == 1:
            head = "POST /api/goal-sets/1/examples HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            head += f"Content-Type: multipart/form-data; boundary=b\r\nContent-Length: {300 * 1024 * 1024}\r\n\r\n"
        else:  # chunked: no length to judge by
            head = "POST /api/goal-sets HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            head += "Transfer-Encoding: chunked\r\n\r\n"
        sock = _send_head(server.url, head, b"")
        with sock:
            sock.settimeout(2)
            try:
                for _ in range(8):
                    piece = chunk if kind != 2 else b"%x\r\n%s\r\n" % (len(chunk), chunk)
                    sock.sendall(piece)
            except OSError:
                pass  # the server answered and closed the connection: that is the point
            try:
                statuses.append(_response_status(sock))
            except (OSError, IndexError, ValueError):
                statuses.append(0)  # reset before the status line could be read
    elapsed = time.monotonic() - started
    time.sleep(0.5)
    after = server.rss_bytes()
    print(f"flood: RSS {before / 2**20:.1f} -> {after / 2**20:.1f} MiB in {elapsed:.1f} s; statuses {set(statuses)}")
    assert set(statuses) <= {401, 0} and statuses.count(401) >= 30, statuses
    assert after - before < 25 * 2**20, (before, after)
    assert elapsed < 60
    with httpx_client(server.url) as client:
        assert client.get("/health").status_code == 200


# ---------------------------------------------------------------- 4. sessions, rate limit, headers
def test_sessions_are_server_side_and_an_operator_can_end_them_all(
    make_client: Callable[..., TestClient], make_settings: Callable[..., Settings], store: Store
) -> None:
    browsers = [make_client(api_token=TOKEN) for _ in range(2)]
    for browser in browsers:
        assert browser.post("/login", data={"token": TOKEN}, follow_redirects=False).status_code == 303
        assert browser.get("/api/runs").status_code == 200
    assert store.count_sessions() == 2
    settings = make_settings(api_token=TOKEN)
    env = {"RAQ_DATABASE_URL": settings.resolved_database_url, "RAQ_DATA_DIR": str(settings.data_dir), "PATH": ""}
    result = subprocess.run(
        [sys.executable, "-m", "cli", "sessions", "--end-all"], cwd=ROOT, env=env, capture_output=True,
        text=True, timeout=120, check=False,
    )  # fmt: skip
    assert result.returncode == 0 and "ended 2 login session(s)" in result.stdout, result.stdout + result.stderr
    for browser in browsers:
        assert browser.get("/api/runs").status_code == 401
        assert browser.get("/", follow_redirects=False).status_code == 303
    # a new token ends the sessions made under the old one
    browser = browsers[0]
    assert browser.post("/login", data={"token": TOKEN}, follow_redirects=False).status_code == 303
    assert browser.get("/api/runs").status_code == 200
    rotated = make_client(api_token="a-new-token")
    rotated.cookies.set("raq_session", browser.cookies["raq_session"])
    assert rotated.get("/api/runs").status_code == 401
    # an expired session no longer works
    with store.writing() as session:
        session.execute(sa.text("UPDATE login_sessions SET expires_at = :now"), {"now": utcnow()})
    assert browser.get("/api/runs").status_code == 401


def test_login_is_rate_limited(make_client: Callable[..., TestClient]) -> None:
    client = make_client(api_token=TOKEN, login_attempts_per_minute=5)
    for _ in range(5):
        assert client.post("/login", data={"token": "guess"}).status_code == 401
    limited = client.post("/login", data={"token": "guess"})
    assert limited.status_code == 429 and 1 <= int(limited.headers["retry-after"]) <= 60
    assert "Too many" in limited.text
    # even the right token waits until the window has passed
    assert client.post("/login", data={"token": TOKEN}, follow_redirects=False).status_code == 429


def test_the_login_limit_is_one_for_every_server_process_and_ends_with_its_window(
    make_client: Callable[..., TestClient], store: Store
) -> None:
    """Two server processes on one database (two apps here): wrong tokens at either count against one limit, kept
    in the database, and once the failures are older than 60 s (the database's clock) the address may try again."""
    first = make_client(api_token=TOKEN, login_attempts_per_minute=4)
    second = make_client(api_token=TOKEN, login_attempts_per_minute=4)
    for client in (first, second, first, second):
        assert client.post("/login", data={"token": "guess"}).status_code == 401
    for client in (first, second):
        refused = client.post("/login", data={"token": TOKEN}, follow_redirects=False)
        assert refused.status_code == 429 and 55 <= int(refused.headers["retry-after"]) <= 60

    def failures() -> int:
        with store.reading() as session:
            return session.scalar(sa.select(sa.func.count()).select_from(LoginFailure)) or 0

    assert failures() == 4  # the refused tries were not counted
    with store.writing() as session:  # the two oldest failures age past the window: two more tries
        oldest = session.scalars(sa.select(LoginFailure.id).order_by(LoginFailure.id).limit(2)).all()
        aged = utcnow() - timedelta(seconds=61)
        session.execute(sa.update(LoginFailure).where(LoginFailure.id.in_(oldest)).values(failed_at=aged))
    assert second.post("/login", data={"token": "guess"}).status_code == 401
    assert failures() == 3  # the aged rows went when the next try was counted
    assert first.post("/login", data={"token": TOKEN}, follow_redirects=False).status_code == 303
    assert failures() == 3  # a right token is not a failure


def test_parallel_guesses_from_one_address_cannot_all_pass_the_login_limit(store: Store) -> None:
    """The check and the count are one step per address: of 12 tries at once, exactly the limit's 5 may go on."""
    with ThreadPoolExecutor(max_workers=12) as pool:
        waits = list(pool.map(lambda _: store.login_attempt(client="10.9.9.9", per_minute=5), range(12)))
    assert waits.count(None) == 5 and all(wait is not None and 1 <= wait <= 60 for wait in waits if wait is not None)
    assert store.login_attempt(client="10.9.9.10", per_minute=5) is None  # another address is not limited


def test_every_response_carries_nosniff_and_a_content_security_policy(
    make_client: Callable[..., TestClient], goal_set_with_photo: dict, client: TestClient
) -> None:
    locked = make_client(api_token=TOKEN)
    responses = [
        client.get("/"), client.get("/queue"), client.get(f"/goal-sets/{goal_set_with_photo['id']}"),
        client.get("/api/runs"), client.get("/api/runs/99"), client.get("/static/app.js"), client.get("/health"),
        client.get("/api/goal-examples/1/image"), client.get("/api/runs/x"), client.get("/nowhere"),
        locked.get("/api/runs"), locked.get("/", follow_redirects=False), locked.get("/login"),
        client.post("/api/goal-sets", content=b"x" * (2 * 1024 * 1024), headers={"Content-Type": "application/json"}),
    ]  # fmt: skip
    for response in responses:
        assert response.headers["x-content-type-options"] == "nosniff", response.url
        csp = response.headers["content-security-policy"]
        assert "script-src 'self';" in csp and "frame-ancestors 'none'" in csp and "object-src 'none'" in csp
        assert response.headers["x-frame-options"] == "DENY"
    docs = client.get("/docs")  # Swagger UI served by the app: no CDN, no inline script
    assert "cdn.jsdelivr.net" not in docs.headers["content-security-policy"] and "/static/swagger-ui/" in docs.text
    assert "'unsafe-inline'" not in docs.headers["content-security-policy"].split("script-src")[1].split(";")[0]


# ---------------------------------------------------------------- 5. failure reasons, counts, the next query
def test_a_failure_reason_names_the_error_not_sqlalchemys_footer(tmp_path) -> None:  # type: ignore[no-untyped-def]
    engine = sa.create_engine(f"sqlite:///{tmp_path / 'x.sqlite3'}")
    try:
        with engine.connect() as connection:
            connection.execute(sa.text("SELECT *\nFROM no_such_table\nWHERE id = :id"), {"id": 1})
    except sa.exc.OperationalError as error:
        reason = first_line(error)
    engine.dispose()
    assert "Background on this error" not in reason and "WHERE" not in reason
    assert reason == "OperationalError: (sqlite3.OperationalError) no such table: no_such_table"
    assert first_line(ValueError("bad\nthing")) == "ValueError: bad"


def _median_ms(client, url: str, repeats: int = 15) -> float:  # type: ignore[no-untyped-def]
    timings = []
    for _ in range(repeats):
        started = time.perf_counter()
        response = client.get(url)
        timings.append((time.perf_counter() - started) * 1000)
        assert response.status_code == 200, (url, response.text)
    return sorted(timings)[len(timings) // 2]


@pytest.mark.slow
def test_next_query_and_pages_stay_fast_with_50k_pending(live_server: str, store: Store) -> None:
    """Were: /api/queries/next loaded every pending row (2.7-4.9 s at 50K); every page loaded up to 10K rows."""
    goal_set = store.create_goal_set(name="g")
    png = image_bytes((48, 48))
    store.add_goal_example(
        goal_set_id=goal_set.id, filename="g.png", original=png, original_media_type="image/png", width=48,
        height=48, model_png=png, display_png=png,
    )  # fmt: skip
    runs = [
        store.create_run(env_id="VisualPusher-v0", algorithm="vice_raq", config={}, goal_set_id=goal_set.id).id
        for _ in range(2)
    ]
    tiny = image_bytes((8, 8))
    now = utcnow()
    rows = [
        {"run_id": runs[index % 2], "env_step": index, "score": 0.1, "strategy": "argmax", "info": {},
         "model_png": tiny, "display_png": tiny, "status": "pending", "created_at": now}
        for index in range(50_000)
    ]  # fmt: skip
    with store.writing() as session:
        session.execute(sa.insert(Query), rows)
    store.answer_query(query_id=1, success=True)
    with store.reading() as session:  # one indexed lookup, not a scan
        plan = " ".join(
            str(row[-1])
            for row in session.execute(
                sa.text("EXPLAIN QUERY PLAN SELECT id FROM queries WHERE status = 'pending' ORDER BY id LIMIT 1")
            )
        )
    assert "ix_queries_status_id" in plan, plan
    with httpx_client(live_server) as client:
        item = client.get("/api/queries/next").json()
        assert (item["query"]["id"], item["pending"], item["pending_all_runs"]) == (2, 49_999, 49_999)
        item = client.get(f"/api/queries/next?run_id={runs[1]}").json()
        assert (item["query"]["id"], item["pending"]) == (2, 25_000)
        urls = ["/api/queries/next", f"/api/queries/next?run_id={runs[0]}", "/", "/queue", f"/runs/{runs[0]}"]
        # the best of up to 3 rounds: on a shared 2-core machine one round can fall in a busy moment
        medians = {url: _median_ms(client, url) for url in urls}
        for _ in range(2):
            if all(median < 100 for median in medians.values()):
                break
            medians = {url: min(medians[url], _median_ms(client, url)) for url in urls}
    print("medians (ms) at 50K pending:", {url: round(ms, 1) for url, ms in medians.items()})
    for url, median in medians.items():
        assert median < 100, (url, median)
