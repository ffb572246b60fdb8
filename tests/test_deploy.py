"""The deployment files stay valid: docker-compose.yml parses with web, learner, migrate and postgres."""

import shutil
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def compose(*args: str) -> str:
    command = shutil.which("docker-compose")
    assert command, "docker-compose is installed by `make test` (Debian package docker-compose)"
    return subprocess.run([command, *args], cwd=ROOT, capture_output=True, text=True, check=True).stdout


def test_compose_file_is_valid_and_names_its_services() -> None:
    assert {"migrate", "web", "learner"} <= set(compose("config", "--services").split())
    assert "profiles:\n    - postgres" in compose("config")  # PostgreSQL only when asked for
    assert set(compose("--profile", "postgres", "config", "--services").split()) == {
        "migrate", "web", "learner", "postgres",
    }  # fmt: skip


def test_web_and_learner_start_after_migrations_and_share_the_data_volume() -> None:
    rendered = compose("config")
    assert rendered.count("condition: service_completed_successfully") == 2
    assert rendered.count("data:/data") == 3  # migrate, web and learner mount the same volume
