"""A local MLflow tracking server (``mlflow server`` of this Python) for the dashboard and for tests:
started on a free port, ready once it answers ``/health``, stopped with all its processes."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

START_TIMEOUT_S = 90.0


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port on ``host`` that nothing listens on now."""
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def answers(url: str, timeout: float = 2.0) -> bool:
    """Whether the MLflow server at ``url`` answers ``/health``."""
    try:
        with urllib.request.urlopen(f"{url}/health", timeout=timeout) as response:
            return response.status == 200
    except (urllib.error.URLError, OSError):
        return False


def _wait_until_ready(process: subprocess.Popen, url: str, log: Path, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not answers(url):
        if process.poll() is not None or time.monotonic() > deadline:
            tail = log.read_text(errors="replace")[-2000:] if log.is_file() else ""
            raise RuntimeError(f"mlflow server at {url} did not start (see {log}):\n{tail}")
        time.sleep(0.25)


def _stop(process: subprocess.Popen) -> None:
    """SIGTERM the server's process group (uvicorn runs in a child), SIGKILL what is left after 10 s."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, signal.SIGTERM)
    try:
        process.wait(timeout=10)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait()


@contextlib.contextmanager
def serve(backend_uri: str, artifacts_dir: Path, log: Path, host: str = "127.0.0.1",
          port: int | None = None, timeout: float = START_TIMEOUT_S) -> Iterator[str]:
    """Run ``mlflow server`` on ``backend_uri`` (e.g. ``sqlite:///mlruns/mlflow.db`` or a PostgreSQL
    URI), serving artefacts of new experiments from ``artifacts_dir``; yields its URL.

    Its output goes to ``log``. The server's job runner (GenAI scorers) is off: one web worker only.
    """
    port = port or free_port(host)
    url = f"http://{host}:{port}"
    command = [sys.executable, "-m", "mlflow", "server", "--backend-store-uri", backend_uri,
               "--artifacts-destination", str(artifacts_dir), "--host", host, "--port", str(port), "--workers", "1"]
    env = {**os.environ, "MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false"}
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "w") as out:
        process = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT, env=env, start_new_session=True)
    try:
        _wait_until_ready(process, url, log, timeout)
        yield url
    finally:
        _stop(process)
