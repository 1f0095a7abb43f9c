"""What the reproduction scripts share: one Hydra multirun of sfc-reconstruct into an MLflow store,
and reading its finished runs and their artefacts back."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from collections.abc import Callable, Hashable, Sequence
from pathlib import Path
from typing import Any

import numpy as np


def run_sweep(store: Path, experiment: str, sweep: Sequence[str], extra: Sequence[str]) -> None:
    """One ``sfc-reconstruct -m`` over the ``sweep`` overrides (e.g. ``experiment=m1,m2v1``), every job
    an MLflow run of ``experiment`` in ``store``; a failed job is reported, the others are kept."""
    cmd = [sys.executable, "-m", "experiments.reconstruct", "-m", *sweep, f"tracking.experiment={experiment}",
           f"tracking.store_dir={store}", *extra]
    done = subprocess.run(cmd, check=False)
    if done.returncode != 0:
        print(f"warning: some jobs failed (exit {done.returncode}); tabulating the finished ones", file=sys.stderr)


def client_for(store: Path) -> Any:
    """An MLflow client of the local store ``store`` (its mlflow.db)."""
    from mlflow.tracking import MlflowClient

    return MlflowClient(tracking_uri=f"sqlite:///{store / 'mlflow.db'}")


def latest_runs(store: Path, experiment: str, key: Callable[[Any], Hashable]) -> tuple[dict[Hashable, Any], Any]:
    """The most recent finished run for each ``key(run)`` (so that one case can be re-run alone)."""
    client = client_for(store)
    found = client.get_experiment_by_name(experiment)
    if found is None:
        raise SystemExit(f"no '{experiment}' experiment in {store}; run without --table-only first")
    runs = client.search_runs([found.experiment_id], "attributes.status = 'FINISHED'",
                              order_by=["attributes.start_time DESC"])
    if not runs:
        raise SystemExit(f"no finished runs in {store}")
    chosen: dict[Hashable, Any] = {}
    for run in runs:
        chosen.setdefault(key(run), run)
    return chosen, client


def artifact(client: Any, run: Any, name: str) -> Any:
    """A run's .json (parsed) or .npy (array) artefact."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(client.download_artifacts(run.info.run_id, name, tmp))
        return json.loads(path.read_text()) if path.suffix == ".json" else np.load(path)


def reproduction_parser(description: str) -> argparse.ArgumentParser:
    """The options every reproduction script takes: --store, --out, --table-only, --overrides."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--store", type=Path, default=Path("mlruns"), help="MLflow store directory")
    parser.add_argument("--out", type=Path, default=Path("docs/results"))
    parser.add_argument("--table-only", action="store_true", help="do not run; build from the latest runs")
    parser.add_argument("--overrides", nargs="*", default=[], help="extra Hydra overrides for every run")
    return parser
