"""Sweeps beyond one machine, on real engines run locally: submitit's local executor (the code
path of the SLURM launcher), a local Ray instance, and a sweep job killed mid-run and run again in
its directory (what a requeue after pre-emption does), which resumes from its checkpoint."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from mlflow.tracking import MlflowClient

from tests.experiments.conftest import SMALL

REPO = Path(__file__).resolve().parents[2]


def _sweep(tmp_path: Path, launcher: list[str], store: Path, extra: list[str] = ()) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "experiments.apps.reconstruct", "-m", "seed=0,1", *SMALL, "solver.max_iter=2",
           f"tracking.store_dir={store}", f"hydra.sweep.dir={tmp_path / 'sweep'}", *launcher, *extra]
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path, env=env)


def _runs(store: Path, sweep: Path | None = None) -> list:
    client = MlflowClient(tracking_uri=f"sqlite:///{store / 'mlflow.db'}")
    runs = client.search_runs([client.get_experiment_by_name("shape-from-caustics").experiment_id])
    return [r for r in runs if sweep is None or r.data.tags.get("sweep_id") == str(sweep)]


@pytest.fixture(scope="module")
def shared_store(tmp_path_factory) -> Path:
    """One MLflow store for the SLURM-path and the Ray sweeps."""
    return tmp_path_factory.mktemp("shared") / "mlruns"


def _check_two_finished_runs(store: Path, sweep: Path) -> None:
    runs = _runs(store, sweep)
    assert sorted(r.data.params["seed"] for r in runs) == ["0", "1"]
    for run in runs:
        assert run.info.status == "FINISHED"
        assert {"rel_error", "rel_discrepancy", "iterations"} <= set(run.data.metrics)
        assert run.data.params["solver.max_iter"] == "2" and len(run.data.params) > 40


@pytest.mark.slow
def test_a_sweep_through_submitits_local_executor(tmp_path, shared_store) -> None:
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    done = _sweep(tmp_path, ["hydra/launcher=submitit_local", "hydra.launcher.timeout_min=10"], shared_store)
    assert done.returncode == 0, done.stderr[-3000:]
    _check_two_finished_runs(shared_store, tmp_path / "sweep")
    assert list((tmp_path / "sweep" / ".submitit").iterdir())  # the jobs went through submitit


@pytest.mark.slow
def test_a_sweep_on_a_local_ray_instance(tmp_path, shared_store) -> None:
    pytest.importorskip("hydra_plugins.hydra_ray_launcher")
    done = _sweep(tmp_path, ["hydra/launcher=ray_cluster", "hydra.launcher.ray.init.num_cpus=2",
                             "+hydra.launcher.ray.init.include_dashboard=false"], shared_store)
    assert done.returncode == 0, done.stderr[-3000:]
    _check_two_finished_runs(shared_store, tmp_path / "sweep")


def _iteration(checkpoint: Path) -> int:
    try:
        return int(torch.load(checkpoint, weights_only=False)["solver_state"]["iteration"])
    except (FileNotFoundError, EOFError, RuntimeError, KeyError):
        return 0


@pytest.mark.slow
def test_a_killed_sweep_job_run_again_resumes_and_ends_as_an_uninterrupted_one(tmp_path) -> None:
    common = [sys.executable, "-m", "experiments.apps.reconstruct", "-m", "seed=3", *SMALL, "solver.max_iter=14",
              "checkpoint_every=2", "stopping=none", f"tracking.store_dir={tmp_path / 'mlruns'}"]
    env = dict(os.environ, PYTHONPATH=str(REPO))
    whole = subprocess.run([*common, f"hydra.sweep.dir={tmp_path / 'whole'}"], capture_output=True, text=True,
                           timeout=600, cwd=tmp_path, env=env)
    assert whole.returncode == 0, whole.stderr[-3000:]
    killed = [*common, f"hydra.sweep.dir={tmp_path / 'killed'}"]
    job = subprocess.Popen(killed, cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                           start_new_session=True)
    checkpoint = tmp_path / "killed" / "0" / "checkpoint.pt"
    deadline = time.monotonic() + 300
    while _iteration(checkpoint) < 6 and job.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    os.killpg(job.pid, signal.SIGKILL)  # pre-empted without warning, mid-run
    job.wait()
    stopped_at = _iteration(checkpoint)
    assert 6 <= stopped_at < 14
    again = subprocess.run(killed, capture_output=True, text=True, timeout=600, cwd=tmp_path, env=env)
    assert again.returncode == 0, again.stderr[-3000:]
    assert f"resuming from {checkpoint}" in again.stdout
    np.testing.assert_array_equal(np.load(tmp_path / "killed" / "0" / "height_field.npy"),
                                  np.load(tmp_path / "whole" / "0" / "height_field.npy"))
    # The resumed job logged into the MLflow run it had started: one run per job, both finished.
    runs = _runs(tmp_path / "mlruns")
    assert len(runs) == 2 and {r.info.status for r in runs} == {"FINISHED"}
    resumed = next(r for r in runs if r.info.run_id != next(
        x.info.run_id for x in runs if x.data.tags.get("sweep_id", "").endswith("whole")))
    steps = sorted({m.step for m in MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'mlruns' / 'mlflow.db'}")
                    .get_metric_history(resumed.info.run_id, "rel_discrepancy")})
    assert steps == list(range(1, 15))
