"""A throwaway MLflow tracking server for tests: ``mlflow server`` on a free local port, its store
and artefacts under the test's temporary directory (or any backend, e.g. PostgreSQL), stopped after."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

from experiments.apps.mlflow_server import serve


@contextlib.contextmanager
def mlflow_server(tmp_path: Path, backend_uri: str | None = None) -> Iterator[str]:
    """Yield the URL (http://127.0.0.1:<port>) of a running server on ``backend_uri`` (default: a
    new SQLite file tmp_path/mlflow.db) with artefacts in tmp_path/artifacts; its log is
    tmp_path/mlflow_server.log."""
    backend = backend_uri or f"sqlite:///{tmp_path / 'mlflow.db'}"
    with serve(backend, tmp_path / "artifacts", tmp_path / "mlflow_server.log") as url:
        yield url
