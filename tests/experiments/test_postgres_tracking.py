"""A shared tracking server on PostgreSQL: 8 runs logging at once through ``mlflow server``, each
with the reconstruction's full parameter set and per-iteration metrics, all of which must arrive.
Needs Debian's postgresql package (skipped where its binaries are absent)."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from mlflow.tracking import MlflowClient

from experiments.apps.configs import to_plain
from framework.core.solver_loop import IterationRecord
from framework.tracking.mlflow_tracker import MlflowTracker, flatten_params
from tests.mlflow_server import mlflow_server
from tests.postgres_server import postgres_bin, postgres_server

CONF = str(Path(__file__).resolve().parents[2] / "conf")
RUNS, ITERATIONS = 8, 30

pytestmark = pytest.mark.skipif(postgres_bin() is None, reason="no PostgreSQL server binaries (Debian postgresql)")


def _config() -> dict:
    with initialize_config_dir(config_dir=CONF, version_base=None):
        return to_plain(compose("reconstruct"))


def _log_run(url: str, index: int, cfg: dict) -> str:
    """One run as sfc-reconstruct logs it: params, then one metrics record per iteration."""
    with MlflowTracker("shared", run_name=f"job-{index}", tracking_uri=url, params={**cfg, "seed": index},
                       tags={"job": str(index)}) as tracker:
        callback = tracker.metrics_callback()
        for k in range(1, ITERATIONS + 1):
            record = IterationRecord(iteration=k, objective=1.0 / k, data_fidelity=1.0 / k,
                                     rel_discrepancy=0.1 + index / k, step_size=1e-3, elapsed_s=0.01 * k)
            callback.on_iteration(None, record)
        return tracker.run_id


@pytest.mark.slow
def test_eight_concurrent_runs_all_arrive(tmp_path) -> None:
    pytest.importorskip("psycopg")
    cfg = _config()
    with postgres_server() as database, mlflow_server(tmp_path, backend_uri=database) as url:
        with ProcessPoolExecutor(max_workers=RUNS) as pool:
            run_ids = list(pool.map(_log_run, [url] * RUNS, range(RUNS), [cfg] * RUNS))
        client = MlflowClient(tracking_uri=url)
        runs = {run.info.run_id: run for run in
                client.search_runs([client.get_experiment_by_name("shared").experiment_id], max_results=100)}
        assert sorted(runs) == sorted(run_ids)
        expected = flatten_params({**cfg, "seed": 0})
        for run_id in run_ids:
            run = runs[run_id]
            assert run.info.status == "FINISHED"
            assert set(run.data.params) == set(expected)  # every param arrived
            history = client.get_metric_history(run_id, "rel_discrepancy")
            assert sorted(m.step for m in history) == list(range(1, ITERATIONS + 1))
            index = int(run.data.tags["job"])
            assert run.data.params["seed"] == str(index)
            assert history[-1].value == pytest.approx(0.1 + index / ITERATIONS)
