"""A throw-away PostgreSQL server on 127.0.0.1 (Debian's postgresql package), for the tests and bench/load.py.

with PostgresServer.started() as server:
    store = Store(server.url)
    server.restart()  # `pg_ctl restart -m fast`: every connection drops, the server is back in about a second
"""

import glob
import os
import shutil
import socket
import subprocess
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path


def postgres_binary(name: str) -> str:
    found = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"))
    assert found, f"{name} not found: `make test` installs Debian's postgresql package"
    return found[-1]


def as_server_user(command: list[str]) -> list[str]:
    """PostgreSQL refuses to run as root: as root, run the command as the postgres user."""
    return ["runuser", "-u", "postgres", "--", *command] if os.geteuid() == 0 else command


def free_port() -> int:
    """A free TCP port on 127.0.0.1 for a server the tests start."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@dataclass
class PostgresServer:
    folder: Path
    port: int
    extra_options: str = ""

    @property
    def data(self) -> Path:
        return self.folder / "data"

    @property
    def url(self) -> str:
        """A SQLAlchemy URL of the server's database `raq` (user raq, trust authentication)."""
        return f"postgresql+psycopg://raq@127.0.0.1:{self.port}/raq"

    def pg_ctl(self, *arguments: str, check: bool = True) -> subprocess.CompletedProcess:
        options = f"-p {self.port} -k {self.folder / 'sockets'} -c listen_addresses=127.0.0.1 -c fsync=off"
        command = [postgres_binary("pg_ctl"), "-D", str(self.data), "-o", f"{options} {self.extra_options}".strip()]
        command += ["-l", str(self.folder / "log"), *arguments]
        return subprocess.run(as_server_user(command), check=check, capture_output=True, text=True)

    def stop(self) -> None:
        """Shut the server down fast: every connection dropped, none accepted until start()."""
        self.pg_ctl("-m", "fast", "-w", "stop")

    def start(self) -> None:
        self.pg_ctl("-w", "start")

    def restart(self) -> None:
        """Restart the server the way an operator or a failover does: fast shutdown, every connection dropped."""
        self.pg_ctl("-m", "fast", "-w", "restart")

    @classmethod
    @contextmanager
    def started(cls, *, extra_options: str = "") -> Iterator["PostgresServer"]:
        """initdb in a new folder of /tmp (which the postgres user can reach), start, createdb raq; stopped and
        removed at the end."""
        folder = Path(tempfile.mkdtemp(prefix="raq-pg-"))
        (folder / "sockets").mkdir()
        if os.geteuid() == 0:
            shutil.chown(folder, "postgres")
            shutil.chown(folder / "sockets", "postgres")
        server = cls(folder, free_port(), extra_options)
        run = {"check": True, "capture_output": True, "text": True}
        initdb = [postgres_binary("initdb"), "-D", str(server.data), "-U", "raq", "--auth=trust"]
        subprocess.run(as_server_user(initdb), **run)
        server.pg_ctl("-w", "start")
        try:
            createdb = [postgres_binary("createdb"), "-h", "127.0.0.1", "-p", str(server.port), "-U", "raq", "raq"]
            subprocess.run(as_server_user(createdb), **run)
            yield server
        finally:
            server.pg_ctl("-m", "fast", "-w", "stop", check=False)
            shutil.rmtree(folder, ignore_errors=True)
