"""The deployment files stay valid: docker-compose.yml parses with web, learner, migrate and postgres, and its scale
profile (learner replicas, PostgreSQL, MinIO)."""

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
    assert set(compose("--profile", "postgres", "config", "--services").split()) >= {
        "migrate",
        "web",
        "learner",
        "postgres",
    }  # fmt: skip  (docker-compose 1.29 lists the services of every profile)


def test_web_and_learner_start_after_migrations_and_share_the_data_volume() -> None:
    rendered = compose("config")
    assert rendered.count("condition: service_completed_successfully") == 4  # web, learner; learners: migrate, bucket
    assert rendered.count("data:/data") == 3  # migrate, web and learner mount the same volume


def test_the_scale_profile_runs_learner_replicas_on_postgresql_and_an_s3_store() -> None:
    """Learner replicas with no shared volume: only PostgreSQL and the checkpoint bucket (MinIO) between them."""
    assert set(compose("--profile", "scale", "config", "--services").split()) >= {
        "migrate", "web", "learner", "postgres", "learners", "minio", "bucket",
    }  # fmt: skip
    rendered = subprocess.run(
        [shutil.which("docker-compose") or "docker-compose", "--profile", "scale", "config"], cwd=ROOT,
        capture_output=True, text=True, check=True, env={"PATH": "/usr/bin:/bin", "RAQ_LEARNERS": "4"},
    ).stdout  # fmt: skip
    learners = rendered.split("\n  learners:\n", 1)[1].split("\n  migrate:\n", 1)[0]  # (sorted by name)
    assert "replicas: 4" in learners and "volumes: []" in learners and "data:/data" not in learners
    assert "RAQ_CHECKPOINT_URL: s3://raq-checkpoints/runs" in learners
    assert "AWS_ENDPOINT_URL: http://minio:9000" in learners
    assert "DATABASE_URL: postgresql+psycopg://raq:raq@postgres/raq" in learners
