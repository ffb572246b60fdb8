"""One Settings object for every process, read from RAQ_* environment variables (and .env)."""

import ipaddress
from functools import lru_cache
from pathlib import Path
from typing import Annotated

from pydantic import AliasChoices, Field, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict


class Settings(BaseSettings):
    """Configuration shared by `raq serve`, `raq learn`, `raq oracle` and `raq up`."""

    model_config = SettingsConfigDict(env_prefix="RAQ_", env_file=".env", extra="ignore")

    data_dir: Path = Field(default=Path("data"), description="The SQLite file and (by default) checkpoints.")
    database_url: str | None = Field(
        default=None,
        validation_alias=AliasChoices("RAQ_DATABASE_URL", "DATABASE_URL"),
        description="SQLAlchemy URL; default a SQLite file under data_dir. PostgreSQL: postgresql+psycopg://…",
    )
    host: str = Field(default="127.0.0.1", description="Address the web server binds.")
    port: int = Field(default=8000, ge=1, le=65535, description="Port the web server binds.")
    api_token: str | None = Field(
        default=None,
        description="When set, every request but /login, /health and /static needs 'Authorization: Bearer <token>' "
        "or a login session.",
    )
    session_max_age_seconds: int = Field(
        default=30 * 24 * 3600, ge=60, le=365 * 24 * 3600, description="A login session ends this long after login."
    )
    login_attempts_per_minute: int = Field(
        default=10, ge=1, le=10_000, description="Failed /login attempts one client address may make per minute."
    )
    trusted_proxies: Annotated[tuple[str, ...], NoDecode] = Field(
        default=(),
        description="Addresses or networks (10.0.0.5, 10.0.0.0/8, ::1) of the reverse proxies in front of the web "
        "server. Only a request that arrives from one of them has its X-Forwarded-For read, for the client address "
        "the login and token rate limit counts (and sessions record); from anywhere else, loopback included, the "
        "header is ignored. Empty (the default): never read. Comma-separated in RAQ_TRUSTED_PROXIES.",
    )
    """Reverse proxies whose X-Forwarded-For is believed (RAQ_TRUSTED_PROXIES, comma-separated); empty: none."""
    max_json_bytes: int = Field(
        default=1024 * 1024, ge=1024, le=64 * 1024 * 1024, description="Largest body of any request but an upload."
    )
    env_modules: Annotated[tuple[str, ...], NoDecode] = Field(
        default=(),
        description="Python modules (and their submodules) a run may name as 'module:EnvId'; the learner imports "
        "no other module for an env. Comma-separated in RAQ_ENV_MODULES.",
    )
    robots: Annotated[tuple[str, ...], NoDecode] = Field(
        default=(),
        description="Robot env ids whose own process (`raq robot ENV`: camera and arm) `raq up` starts and keeps "
        "running on this host. Comma-separated in RAQ_ROBOTS.",
    )
    server_url: str | None = Field(default=None, description="Base URL the oracle talks to.")
    max_upload_bytes: int = Field(default=20 * 1024 * 1024, description="Largest accepted upload.")
    max_image_pixels: int = Field(default=40_000_000, description="Largest accepted decoded image (w*h).")
    checkpoint_url: str | None = Field(
        default=None,
        description="Where checkpoints live: a directory or an fsspec URL such as s3://bucket/prefix (credentials "
        "and AWS_ENDPOINT_URL from the standard AWS environment variables); default data_dir/checkpoints.",
    )
    stale_heartbeat_seconds: float = Field(
        default=60.0, description="A training run whose heartbeat is older than this is reclaimed."
    )
    database_patience_seconds: float = Field(
        default=600.0, gt=0,
        description="How long a learner waits out an unreachable database, retrying each call with backoff, before "
        "it gives its run back to the queue (to resume from its last checkpoint once the database is back).",
    )  # fmt: skip

    @field_validator("env_modules", "robots", mode="before")
    @classmethod
    def _split_modules(cls, value: object) -> object:
        if isinstance(value, str):
            return tuple(name.strip() for name in value.split(",") if name.strip())
        return value

    @field_validator("env_modules")
    @classmethod
    def _module_names(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        for name in value:
            if not all(part.isidentifier() for part in name.split(".")):
                raise ValueError(f"{name!r} is not a Python module name")
        return value

    @field_validator("trusted_proxies", mode="before")
    @classmethod
    def _split_proxies(cls, value: object) -> object:
        if isinstance(value, str):
            return tuple(item.strip() for item in value.split(",") if item.strip())
        return value

    @field_validator("trusted_proxies")
    @classmethod
    def _proxy_networks(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        for item in value:
            try:
                ipaddress.ip_network(item, strict=False)
            except ValueError:
                raise ValueError(f"{item!r} is not an IP address or network (such as 10.0.0.5 or 10.0.0.0/8)") from None
        return value

    @field_validator("api_token")
    @classmethod
    def _empty_token_is_none(cls, value: str | None) -> str | None:
        return value or None

    @property
    def resolved_database_url(self) -> str:
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'raq.sqlite3').resolve()}"

    @property
    def checkpoint_dir(self) -> Path:
        return self.data_dir / "checkpoints"

    @property
    def resolved_checkpoint_url(self) -> str:
        """RAQ_CHECKPOINT_URL, or the local data_dir/checkpoints."""
        return self.checkpoint_url or str(self.checkpoint_dir)

    @property
    def base_url(self) -> str:
        return self.server_url or f"http://{self.host}:{self.port}"


@lru_cache
def get_settings() -> Settings:
    return Settings()
