"""What the reproduction scripts share: one Hydra multirun of sfc-reconstruct into an MLflow store
(a local directory, or a tracking server shared by the jobs of a cluster), on any Hydra launcher,
and reading its finished runs and their artefacts back."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from framework.tracking.tracking_target import local_store_uri


@dataclass(frozen=True)
class TrackingStore:
    """Where runs are logged and read back: ``directory`` (local SQLite store and artefacts), or the
    tracking server at ``uri`` (http(s)://...; artefacts then go where the server keeps them)."""

    directory: Path
    uri: str | None = None

    def client(self) -> Any:
        """An MLflow client of this store."""
        from mlflow.tracking import MlflowClient

        return MlflowClient(tracking_uri=self.uri or local_store_uri(self.directory))

    def overrides(self) -> list[str]:
        """The sfc-reconstruct overrides that log to this store."""
        return [f"tracking.store_dir={self.directory}", *([f"tracking.uri={self.uri}"] if self.uri else [])]


def tracking_store(args: argparse.Namespace) -> TrackingStore:
    """The store of a reproduction script's --store and --tracking-uri options."""
    return TrackingStore(args.store.resolve(), args.tracking_uri)


def run_sweep(store: TrackingStore, experiment: str, sweep: Sequence[str], extra: Sequence[str],
              launcher: str | None = None, app: str = "experiments.apps.reconstruct") -> None:
    """One multirun of the Hydra ``app`` (default ``sfc-reconstruct``) over the ``sweep`` overrides
    (e.g. ``experiment=m1,m2v1``), every job an MLflow run of ``experiment`` in ``store``, launched by
    the Hydra ``launcher`` (a name in conf/hydra/launcher/, e.g. slurm; None: one job after the other
    here); a failed job is reported, the others are kept."""
    cmd = [sys.executable, "-m", app, "-m", *sweep, f"tracking.experiment={experiment}",
           *store.overrides(), *([f"hydra/launcher={launcher}"] if launcher else []), *extra]
    done = subprocess.run(cmd, check=False)
    if done.returncode != 0:
        print(f"warning: some jobs failed (exit {done.returncode}); tabulating the finished ones", file=sys.stderr)


def latest_runs(store: TrackingStore, experiment: str, key: Callable[[Any], Hashable]
                ) -> tuple[dict[Hashable, Any], Any]:
    """The most recent finished run for each ``key(run)`` (so that one case can be re-run alone)."""
    client = store.client()
    found = client.get_experiment_by_name(experiment)
    if found is None:
        raise SystemExit(
            f"no '{experiment}' experiment in {store.uri or store.directory}; run without --table-only first"
        )
    runs = client.search_runs([found.experiment_id], "attributes.status = 'FINISHED'",
                              order_by=["attributes.start_time DESC"])
    if not runs:
        raise SystemExit(f"no finished runs in {store.uri or store.directory}")
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
    """The options every reproduction script takes: --store, --tracking-uri, --launcher, --out,
    --table-only, --overrides."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--store", type=Path, default=Path("mlruns"), help="MLflow store directory")
    parser.add_argument("--tracking-uri", default=None,
                        help="a shared MLflow tracking server (http(s)://host:port) instead of --store")
    parser.add_argument("--launcher", default=None,
                        help="Hydra launcher of the runs (conf/hydra/launcher/: parallel, slurm, ray_cluster)")
    parser.add_argument("--out", type=Path, default=Path("docs/results"))
    parser.add_argument("--table-only", action="store_true", help="do not run; build from the latest runs")
    parser.add_argument("--overrides", nargs="*", default=[], help="extra Hydra overrides for every run")
    return parser
