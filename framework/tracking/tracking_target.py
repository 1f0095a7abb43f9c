"""Where an MLflow run is logged, checked before it opens: the known URI schemes, a tracking server
that must answer as MLflow, and the local store's SQLite file."""

from __future__ import annotations

import os
import urllib.error
import urllib.request
from pathlib import Path

from framework.files.paths import check_creatable_directory

__all__ = ["KNOWN_SCHEMES", "check_target", "check_tracking_server", "local_store_uri"]

KNOWN_SCHEMES = ("sqlite", "file", "http", "https", "postgresql", "postgresql+psycopg2", "mysql",
                 "mysql+pymysql", "mssql", "databricks")


def check_tracking_server(uri: str, timeout: float = 5.0) -> None:
    """Refuse an http(s) tracking URI whose server does not answer, or answers but is not an
    MLflow server (its ``/health`` must answer OK); other URIs pass."""
    if not uri.startswith(("http://", "https://")):
        return
    fix = "start one (mlflow server --host <host> --port <port>) or set tracking.uri=null for the local store"
    try:
        with urllib.request.urlopen(f"{uri.rstrip('/')}/health", timeout=timeout) as answer:
            body = answer.read(64).decode("utf-8", "replace").strip()
    except urllib.error.HTTPError as error:
        raise ValueError(f"tracking.uri={uri} answers but is not an MLflow server (/health: HTTP {error.code}); "
                         f"{fix}") from None
    except (urllib.error.URLError, OSError) as error:
        reason = getattr(error, "reason", error)
        raise ValueError(f"the MLflow tracking server tracking.uri={uri} does not answer ({reason}); {fix}") from None
    if body != "OK":
        raise ValueError(f"tracking.uri={uri} answers but is not an MLflow server (/health: {body[:40]!r}); {fix}")


def local_store_uri(store_dir: str | os.PathLike[str]) -> str:
    """The tracking URI of the local store in ``store_dir``: its SQLite file mlflow.db."""
    return f"sqlite:///{Path(store_dir).resolve() / 'mlflow.db'}"


def check_target(uri: str | None, store_dir: Path) -> None:
    """Refuse, before a run opens, a tracking target that cannot take it: an unknown URI scheme, a
    server that is not MLflow, or (``uri`` None) a local ``store_dir`` that is a file or lies
    under one or in a directory that cannot be written."""
    if uri is not None:
        if not isinstance(uri, str) or not uri:
            raise ValueError(f"tracking.uri={uri!r} must be an MLflow tracking URI (e.g. http://host:5000, "
                             "sqlite:///path/mlflow.db) or null for the local store tracking.store_dir")
        scheme = uri.split("://", 1)[0].lower() if "://" in uri else ""
        if scheme and scheme not in KNOWN_SCHEMES:
            raise ValueError(f"tracking.uri={uri}: unknown scheme {scheme!r}; use one of {', '.join(KNOWN_SCHEMES)} "
                             "or tracking.uri=null for the local store tracking.store_dir")
        check_tracking_server(uri)
        return
    check_creatable_directory(store_dir, "tracking.store_dir")
