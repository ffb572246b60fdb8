"""Health, and write authorisation with and without RAQ_API_TOKEN."""

from collections.abc import Callable

from fastapi.testclient import TestClient

TOKEN = "s3cret-token"


def test_health_reports_database(client: TestClient) -> None:
    response = client.get("/health")
    assert response.status_code == 200
    assert response.json() == {"status": "ok", "database": "ok"}


def test_without_token_writes_need_no_auth(client: TestClient) -> None:
    assert client.post("/api/goal-sets", json={"name": "open"}).status_code == 201
    assert client.get("/login").status_code == 200


def test_with_token_every_request_needs_it(make_client: Callable[..., TestClient]) -> None:
    client = make_client(api_token=TOKEN)
    # only /health, /login and /static are public
    assert client.get("/health").status_code == 200
    assert client.get("/login").status_code == 200
    assert client.get("/static/style.css").status_code == 200
    # API reads and the spec without the token: 401 with a message saying what to do
    for url in ["/api/goal-sets", "/api/runs", "/api/runs/1", "/api/queries", "/api/queries/next", "/openapi.json"]:
        response = client.get(url)
        assert response.status_code == 401, url
        assert "Bearer" in response.json()["detail"]
        assert response.headers["www-authenticate"] == "Bearer"
    # pages redirect to the login, which brings the browser back
    for url in ["/", "/queue?run=1", "/goal-sets", "/runs/new", "/runs/1", "/docs"]:
        response = client.get(url, follow_redirects=False)
        assert response.status_code == 303, url
        assert response.headers["location"].startswith("/login?next=%2F"), url
    assert "next=%2Fqueue%3Frun%3D1" in client.get("/queue?run=1", follow_redirects=False).headers["location"]
    # writes without or with a wrong token
    response = client.post("/api/goal-sets", json={"name": "locked"})
    assert response.status_code == 401
    wrong = {"Authorization": "Bearer nope"}
    assert client.post("/api/goal-sets", json={"name": "locked"}, headers=wrong).status_code == 401
    assert client.get("/api/goal-sets", headers=wrong).status_code == 401
    for method, url in [
        ("POST", "/api/runs"),
        ("POST", "/api/runs/1/stop"),
        ("POST", "/api/runs/1/resume"),
        ("POST", "/api/queries/1/answer"),
        ("POST", "/api/queries/1/skip"),
        ("POST", "/api/queries/1/undo"),
        ("DELETE", "/api/goal-sets/1"),
        ("DELETE", "/api/goal-examples/1"),
        ("POST", "/api/goal-sets/1/examples"),
    ]:
        assert client.request(method, url, json={}).status_code == 401, (method, url)
    # the right bearer token works for reads and writes
    good = {"Authorization": f"Bearer {TOKEN}"}
    assert client.get("/api/goal-sets", headers=good).json() == []
    assert client.post("/api/goal-sets", json={"name": "unlocked"}, headers=good).status_code == 201
    assert client.get("/openapi.json", headers=good).status_code == 200


def test_login_session_authorises_pages_and_logout_ends_it(make_client: Callable[..., TestClient]) -> None:
    client = make_client(api_token=TOKEN)
    page = client.get("/queue")  # redirected to the login page
    assert page.url.path == "/login" and "log in" in page.text.lower()
    bad = client.post("/login", data={"token": "wrong", "next": "/queue"}, follow_redirects=False)
    assert bad.status_code == 401
    assert "not right" in bad.text
    response = client.post("/login", data={"token": TOKEN, "next": "/queue"}, follow_redirects=False)
    assert response.status_code == 303
    assert response.headers["location"] == "/queue"
    cookie_header = response.headers["set-cookie"].lower()
    assert "httponly" in cookie_header and "samesite=strict" in cookie_header
    assert TOKEN not in response.headers["set-cookie"]  # the cookie holds a random session secret
    secret = client.cookies["raq_session"]
    assert client.post("/api/goal-sets", json={"name": "via cookie"}).status_code == 201
    assert client.get("/api/goal-sets").status_code == 200
    assert "Log out" in client.get("/").text
    assert client.post("/logout", follow_redirects=False).status_code == 303
    # the same cookie, sent again after the logout, no longer works: the session ended on the server
    client.cookies.set("raq_session", secret)
    assert client.post("/api/goal-sets", json={"name": "after logout"}).status_code == 401
    assert client.get("/api/goal-sets").status_code == 401


def test_login_redirect_stays_on_site(make_client: Callable[..., TestClient]) -> None:
    client = make_client(api_token=TOKEN)
    response = client.post("/login", data={"token": TOKEN, "next": "//evil.example/"}, follow_redirects=False)
    assert response.headers["location"] == "/"


def test_openapi_lists_the_api(client: TestClient) -> None:
    paths = client.get("/openapi.json").json()["paths"]
    for path in ["/api/runs", "/api/goal-sets/{goal_set_id}/examples", "/api/queries/{query_id}/answer",
                 "/api/runs/{run_id}/metrics", "/api/runs/{run_id}/events", "/health"]:  # fmt: skip
        assert path in paths
    assert client.get("/docs").status_code == 200


EVIL = "http://evil.example"


def test_without_token_cross_site_writes_are_refused(client: TestClient, make_image: Callable[..., bytes]) -> None:
    """Any page the user visits could POST to 127.0.0.1:8000 (forms, no-cors fetches): browsers label it."""
    for headers in [
        {"Origin": EVIL},
        {"Origin": "null"},  # sandboxed frames, file: pages
        {"Origin": "http://testserver:8080"},  # another port on the same host is another origin
        {"Sec-Fetch-Site": "cross-site"},
    ]:
        response = client.post("/api/goal-sets", json={"name": "csrf"}, headers=headers)
        assert response.status_code == 403, (headers, response.text)
        assert "another web site" in response.json()["detail"]
    png = make_image()
    upload = client.post(
        "/api/goal-sets/1/examples", files=[("files", ("a.png", png, "image/png"))], headers={"Origin": EVIL}
    )
    assert upload.status_code == 403
    for method, url in [("POST", "/api/runs"), ("POST", "/api/queries/1/answer"), ("DELETE", "/api/goal-sets/1")]:
        assert client.request(method, url, json={}, headers={"Origin": EVIL}).status_code == 403, (method, url)
    assert client.get("/api/goal-sets").json() == []
    # our own pages' fetches (Origin == Host) and programs without Origin (curl, httpx, the oracle) still write
    same_origin = {"Origin": "http://testserver", "Sec-Fetch-Site": "same-origin"}
    assert client.post("/api/goal-sets", json={"name": "page"}, headers=same_origin).status_code == 201
    assert client.post("/api/goal-sets", json={"name": "program"}).status_code == 201
    # a browser's plain reads stay open
    assert client.get("/api/goal-sets", headers={"Origin": EVIL, "Sec-Fetch-Site": "cross-site"}).status_code == 200


def test_without_token_only_loopback_host_names_are_served(client: TestClient) -> None:
    """DNS rebinding: evil.example resolving to 127.0.0.1 reaches the server with Host: evil.example."""
    for host in ["evil.example", "evil.example:8000", "192.168.1.5:8000"]:
        response = client.get("/api/goal-sets", headers={"Host": host})
        assert response.status_code == 400, host
        rebinding = {"Host": host, "Origin": f"http://{host}"}  # same-origin as far as the browser knows
        assert client.post("/api/goal-sets", json={"name": "rebound"}, headers=rebinding).status_code == 400, host
    for host in ["127.0.0.1:8000", "localhost:8000", "[::1]:8000", "localhost"]:
        assert client.get("/health", headers={"Host": host}).status_code == 200, host
    same_origin = {"Host": "127.0.0.1:8000", "Origin": "http://127.0.0.1:8000"}
    assert client.post("/api/goal-sets", json={"name": "local page"}, headers=same_origin).status_code == 201
    assert [g["name"] for g in client.get("/api/goal-sets").json()] == ["local page"]


def test_with_token_cross_site_checks_still_apply(make_client: Callable[..., TestClient]) -> None:
    client = make_client(api_token=TOKEN)
    good = {"Authorization": f"Bearer {TOKEN}"}
    # with a token the server may be served under any name (behind a proxy, in docker)
    assert client.get("/health", headers={"Host": "raq.example.org"}).status_code == 200
    refused = client.post("/api/goal-sets", json={"name": "x"}, headers={**good, "Origin": EVIL})
    assert refused.status_code == 403
    assert client.post("/login", data={"token": TOKEN}, headers={"Origin": EVIL}).status_code == 403
    assert client.post("/logout", headers={"Sec-Fetch-Site": "cross-site"}).status_code == 403
    behind_proxy = {"Host": "raq.example.org", "Origin": "https://raq.example.org"}
    assert client.post("/api/goal-sets", json={"name": "y"}, headers={**good, **behind_proxy}).status_code == 201
    assert client.post("/login", data={"token": TOKEN}, headers=behind_proxy, follow_redirects=False).status_code == 303
    assert [g["name"] for g in client.get("/api/goal-sets", headers=good).json()] == ["y"]
