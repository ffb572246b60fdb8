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


def test_with_token_every_write_needs_it(make_client: Callable[..., TestClient]) -> None:
    client = make_client(api_token=TOKEN)
    # reads stay open
    assert client.get("/api/goal-sets").status_code == 200
    assert client.get("/health").status_code == 200
    assert client.get("/").status_code == 200
    # writes without or with a wrong token: 401 with a message saying what to do
    response = client.post("/api/goal-sets", json={"name": "locked"})
    assert response.status_code == 401
    assert "Bearer" in response.json()["detail"]
    assert response.headers["www-authenticate"] == "Bearer"
    wrong = {"Authorization": "Bearer nope"}
    assert client.post("/api/goal-sets", json={"name": "locked"}, headers=wrong).status_code == 401
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
    assert client.get("/api/goal-sets").json() == []
    # the right bearer token works
    good = {"Authorization": f"Bearer {TOKEN}"}
    assert client.post("/api/goal-sets", json={"name": "unlocked"}, headers=good).status_code == 201


def test_login_cookie_authorises_page_writes(make_client: Callable[..., TestClient]) -> None:
    client = make_client(api_token=TOKEN)
    page = client.get("/queue")
    assert "log in" in page.text.lower()
    bad = client.post("/login", data={"token": "wrong", "next": "/queue"}, follow_redirects=False)
    assert bad.status_code == 401
    assert "not right" in bad.text
    response = client.post("/login", data={"token": TOKEN, "next": "/queue"}, follow_redirects=False)
    assert response.status_code == 303
    assert response.headers["location"] == "/queue"
    cookie_header = response.headers["set-cookie"].lower()
    assert "httponly" in cookie_header and "samesite=strict" in cookie_header
    assert TOKEN not in response.headers["set-cookie"]  # the cookie holds a keyed hash, not the token
    assert client.post("/api/goal-sets", json={"name": "via cookie"}).status_code == 201
    assert "Log out" in client.get("/").text
    client.post("/logout", follow_redirects=False)
    client.cookies.clear()
    assert client.post("/api/goal-sets", json={"name": "after logout"}).status_code == 401


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
