"""Hydra multirun: one MLflow run per job, grouped by the sweep."""

from __future__ import annotations

import subprocess
import sys

import pytest
from mlflow.tracking import MlflowClient

from tests.experiments.conftest import SMALL


@pytest.mark.slow
def test_multirun_logs_one_grouped_mlflow_run_per_job(tmp_path):
    store = tmp_path / "mlruns"
    cmd = [sys.executable, "-m", "experiments.apps.reconstruct", "-m", "experiment=m1,m2v0", *SMALL,
           "solver.max_iter=1", f"tracking.store_dir={store}", f"hydra.sweep.dir={tmp_path / 'sweep'}"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    client = MlflowClient(tracking_uri=f"sqlite:///{store / 'mlflow.db'}")
    runs = client.search_runs([client.get_experiment_by_name("shape-from-caustics").experiment_id])
    assert sorted(r.data.tags["method"] for r in runs) == ["M1", "M2V0"]
    assert {r.info.status for r in runs} == {"FINISHED"}
    sweeps = {r.data.tags.get("sweep_id") for r in runs}
    assert len(sweeps) == 1 and None not in sweeps
    for job in ("0", "1"):
        assert (tmp_path / "sweep" / job / "height_field.npy").is_file()
