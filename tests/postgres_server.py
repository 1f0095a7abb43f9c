"""A throwaway PostgreSQL server for tests: Debian's binaries, a fresh cluster in a temporary
directory, a free local port, stopped afterwards. PostgreSQL refuses to run as root, so as root it
runs as the ``postgres`` system user."""

from __future__ import annotations

import contextlib
import glob
import os
import shutil
import socket
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path


def postgres_bin() -> Path | None:
    """The directory of initdb / pg_ctl (Debian: /usr/lib/postgresql/<version>/bin), or None."""
    found = shutil.which("initdb")
    if found:
        return Path(found).parent
    candidates = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
    return Path(candidates[-1]).parent if candidates else None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def postgres_server() -> Iterator[str]:
    """Start a cluster in a new directory under the system's temporary directory (one the
    ``postgres`` user can reach, unlike pytest's private tmp_path) and remove it afterwards; yields
    its SQLAlchemy URI (postgresql://postgres@127.0.0.1:<port>/postgres)."""
    binaries = postgres_bin()
    if binaries is None:
        raise RuntimeError("no PostgreSQL server binaries (Debian package postgresql)")
    with tempfile.TemporaryDirectory(prefix="sfc-postgres-") as name:
        directory = Path(name)
        os.chmod(directory, 0o755)
        with _cluster(binaries, directory) as uri:
            yield uri


@contextlib.contextmanager
def _cluster(binaries: Path, directory: Path) -> Iterator[str]:
    data = directory / "pgdata"
    data.mkdir(parents=True)
    as_user: list[str] = []
    if os.geteuid() == 0:
        shutil.chown(directory, "postgres")
        shutil.chown(data, "postgres")
        as_user = ["runuser", "-u", "postgres", "--"]
    port = _free_port()
    run = lambda *args: subprocess.run([*as_user, *args], check=True, capture_output=True, text=True,  # noqa: E731
                                       timeout=120)
    run(str(binaries / "initdb"), "-D", str(data), "-U", "postgres", "--auth=trust")
    run(str(binaries / "pg_ctl"), "-D", str(data), "-l", str(directory / "postgres.log"), "-w", "-o",
        f"-p {port} -k {directory} -c listen_addresses=127.0.0.1 -c max_connections=200", "start")
    try:
        yield f"postgresql://postgres@127.0.0.1:{port}/postgres"
    finally:
        run(str(binaries / "pg_ctl"), "-D", str(data), "-m", "fast", "-w", "stop")
