"""New local MLflow stores copied from an empty one: MLflow builds a new SQLite store by running
its schema migrations, about 3 s on 2 cores, where copying a store that has run them takes about
0.05 s. The empty store of the installed MLflow version is built once per machine in the user's
cache (``$XDG_CACHE_HOME`` or ``~/.cache``, folder ``shape-from-caustics``) and copied into
each new store; MLflow opens the copy as it opens any store of its version (its schema revision
is checked on opening).
"""

from __future__ import annotations

import os
import shutil
import sqlite3
import tempfile
from pathlib import Path

__all__ = ["cache_dir", "create_empty_store"]


def cache_dir() -> Path:
    """The folder of this package's caches: $XDG_CACHE_HOME/shape-from-caustics, else ~/.cache/..."""
    root = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(root) / "shape-from-caustics"


def _template() -> Path:
    """The empty store of the installed MLflow version, built on first use (atomically, so that
    processes building it at once each finish with a whole file)."""
    import mlflow
    from mlflow.tracking import MlflowClient

    path = cache_dir() / f"mlflow-{mlflow.__version__}-empty.db"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, scratch = tempfile.mkstemp(suffix=".db", dir=path.parent)
        os.close(handle)
        os.unlink(scratch)  # MLflow creates the file, with its tables
        MlflowClient(tracking_uri=f"sqlite:///{scratch}").search_experiments()
        os.replace(scratch, path)
    return path


def create_empty_store(db_path: Path, artifact_root: str) -> bool:
    """Create the SQLite store ``db_path`` (which must not exist) as a copy of the empty store, its
    Default experiment's artefacts under ``artifact_root`` (a URI) + "/0". Returns False, leaving
    MLflow to build the store itself, where the cache cannot be written or read."""
    try:
        template = _template()
        shutil.copyfile(template, db_path)
    except OSError:
        return False
    db = sqlite3.connect(db_path)
    try:
        with db:
            db.execute("UPDATE experiments SET artifact_location = ? WHERE experiment_id = 0", (f"{artifact_root}/0",))
    finally:
        db.close()
    return True
