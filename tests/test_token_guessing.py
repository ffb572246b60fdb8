"""Guessing the API token costs time: wrong bearer tokens count against the client address's login limit (429 with
Retry-After once over it, the right token included), and X-Forwarded-For is believed only from the proxies the
operator names (RAQ_TRUSTED_PROXIES), so made-up addresses get no fresh allowance."""

import os
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest
from conftest import LiveServer, free_port
from pydantic import ValidationError
from test_processes import wait_for_health

from contract.settings import Settings

TOKEN = "the-right-token"


def bearer(token: str, **extra: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}", **extra}


def test_wrong_bearer_tokens_are_limited_per_address_and_then_even_the_right_one_waits(
    make_live_server: Callable[..., LiveServer],
) -> None:
    server = make_live_server(RAQ_API_TOKEN=TOKEN, RAQ_LOGIN_ATTEMPTS_PER_MINUTE="5")
    with httpx.Client(base_url=server.url, timeout=10) as client:
        assert client.get("/api/runs", headers=bearer(TOKEN)).status_code == 200  # the right token is not counted
        statuses = [client.get("/api/runs", headers=bearer(f"guess-{i}")).status_code for i in range(8)]
        assert statuses == [401] * 5 + [429] * 3
        limited = client.post("/api/goal-sets", json={"name": "x"}, headers=bearer("guess-9"))
        assert limited.status_code == 429 and 1 <= int(limited.headers["retry-after"]) <= 60
        assert "try again in" in limited.json()["detail"]
        # a guess that happens to be right is refused too while the address is limited: guessing gains nothing
        right = client.get("/api/runs", headers=bearer(TOKEN))
        assert right.status_code == 429 and 1 <= int(right.headers["retry-after"]) <= 60
        # the same allowance as the login form: it is used up as well
        login = client.post("/login", data={"token": TOKEN}, follow_redirects=False)
        assert login.status_code == 429
        assert client.get("/health").status_code == 200  # public paths stay open


def test_x_forwarded_for_from_loopback_gives_no_fresh_allowance_under_raq_serve(tmp_path: Path) -> None:
    """`raq serve` as an operator starts it, no proxies named: a guesser on this host who sends a new
    X-Forwarded-For with every guess is still one address."""
    port = free_port()
    env = {
        **os.environ, "RAQ_DATA_DIR": str(tmp_path), "RAQ_PORT": str(port), "RAQ_API_TOKEN": TOKEN,
        "RAQ_LOGIN_ATTEMPTS_PER_MINUTE": "3", "PYTHONUNBUFFERED": "1",
    }  # fmt: skip
    for name in ("RAQ_DATABASE_URL", "DATABASE_URL", "RAQ_TRUSTED_PROXIES", "FORWARDED_ALLOW_IPS"):
        env.pop(name, None)
    with (tmp_path / "serve.log").open("w") as log:
        process = subprocess.Popen(
            [sys.executable, "-m", "cli", "serve"], env=env, stdout=log, stderr=subprocess.STDOUT,
            start_new_session=True,
        )  # fmt: skip
        try:
            wait_for_health(port, process)
            with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=10) as client:
                spoofed = [bearer("guess", **{"X-Forwarded-For": f"203.0.113.{i}"}) for i in range(6)]
                statuses = [client.get("/api/runs", headers=headers).status_code for headers in spoofed]
                login = client.post(
                    "/login", data={"token": "guess"}, headers={"X-Forwarded-For": "198.51.100.7"},
                    follow_redirects=False,
                )  # fmt: skip
        finally:
            os.killpg(process.pid, signal.SIGINT)
            process.wait(timeout=60)
    assert statuses == [401] * 3 + [429] * 3
    assert login.status_code == 429


def test_x_forwarded_for_is_read_from_a_named_proxy_only_for_the_hops_it_added(
    make_live_server: Callable[..., LiveServer],
) -> None:
    """Behind a proxy on 127.0.0.1 (RAQ_TRUSTED_PROXIES), each client address has its own allowance; the
    right-most hop is the one the proxy saw, so a client's own X-Forwarded-For (the left part) changes nothing."""
    server = make_live_server(
        RAQ_API_TOKEN=TOKEN, RAQ_LOGIN_ATTEMPTS_PER_MINUTE="2", RAQ_TRUSTED_PROXIES="127.0.0.1, 10.0.0.0/8"
    )
    with httpx.Client(base_url=server.url, timeout=10) as client:

        def guess(forwarded: str) -> int:
            return client.get("/api/runs", headers=bearer("guess", **{"X-Forwarded-For": forwarded})).status_code

        # one client behind the proxy, spoofing the left part of the header each time: one address, 203.0.113.1
        assert [guess(f"192.0.2.{i}, 203.0.113.1") for i in range(4)] == [401, 401, 429, 429]
        # a chain of two trusted proxies (10.1.2.3 then 127.0.0.1) in front of the same client: still limited
        assert guess("203.0.113.1, 10.1.2.3") == 429
        # another client behind the proxy has its own allowance
        assert [guess("203.0.113.2") for _ in range(3)] == [401, 401, 429]
        # the right token from a client that is not limited passes
        assert client.get("/api/runs", headers=bearer(TOKEN, **{"X-Forwarded-For": "203.0.113.3"})).status_code == 200


def test_trusted_proxies_setting_reads_a_comma_separated_list_of_addresses_and_networks(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    assert Settings(_env_file=None).trusted_proxies == ()  # off by default
    monkeypatch.setenv("RAQ_TRUSTED_PROXIES", "10.0.0.5, 10.0.0.0/8,::1")
    assert Settings(_env_file=None).trusted_proxies == ("10.0.0.5", "10.0.0.0/8", "::1")
    monkeypatch.setenv("RAQ_TRUSTED_PROXIES", "10.0.0.5,proxy.example.org")
    with pytest.raises(ValidationError, match="proxy.example.org"):
        Settings(_env_file=None)
