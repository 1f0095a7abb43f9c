"""A small reconstruction logged to a real MLflow tracking server and read back through its REST API."""

from __future__ import annotations

import json
import re

import pytest
from mlflow.tracking import MlflowClient

from framework.reconstruction.reconstruction import run_reconstruction
from framework.tracking.mlflow_tracker import DATASET_CONTEXT, EXPERIMENT_KIND, EXPERIMENT_KIND_TAG
from tests.experiments.conftest import SMALL, compose_reconstruct
from tests.mlflow_server import mlflow_server

ITERATIONS = 3


@pytest.mark.slow
def test_a_reconstruction_against_a_tracking_server_is_read_back(tmp_path):
    with mlflow_server(tmp_path / "server") as url:
        cfg = compose_reconstruct([*SMALL, f"solver.max_iter={ITERATIONS}", "stopping=none", f"tracking.uri={url}"],
                                  tmp_path)
        metrics = run_reconstruction(cfg, tmp_path / "run", tmp_path)
        client = MlflowClient(tracking_uri=url)
        experiment = client.get_experiment_by_name("shape-from-caustics")
        (run,) = client.search_runs([experiment.experiment_id])
        run_id = run.info.run_id
        objective = client.get_metric_history(run_id, "objective")
        discrepancy = client.get_metric_history(run_id, "rel_discrepancy")
        artifacts = {a.path for a in client.list_artifacts(run_id)}

    assert metrics["iterations"] == ITERATIONS and run.info.status == "FINISHED"
    assert experiment.tags[EXPERIMENT_KIND_TAG] == EXPERIMENT_KIND
    assert run.data.params["solver.max_iter"] == str(ITERATIONS) and run.data.params["data.delta"] == "0.05"
    assert run.data.tags["git_dirty"] in {"true", "false", "unknown"} and run.data.tags["mlflow.source.name"]
    assert re.fullmatch(r"[0-9a-f]{40}|unknown", run.data.tags["mlflow.source.git.commit"])
    assert sorted(m.step for m in objective) == list(range(1, ITERATIONS + 1))  # one point per iteration
    assert min(m.step for m in discrepancy) == 1 and max(m.step for m in discrepancy) == ITERATIONS
    assert run.data.metrics["rel_discrepancy"] == metrics["rel_discrepancy"]  # the summary is the latest value
    (data_input,) = run.inputs.dataset_inputs
    assert data_input.dataset.name == "synthetic:print_lines"
    assert re.fullmatch(r"[0-9a-f]{16}", data_input.dataset.digest)
    assert {t.key: t.value for t in data_input.tags} == {"mlflow.data.context": DATASET_CONTEXT}
    source = json.loads(data_input.dataset.source)["tags"]
    assert source["seed"] == 0 and source["data"]["delta"] == 0.05 and source["height_field"]["shape"] == "print_lines"
    assert {"height_field.npy", "metrics.json", "convergence.png", "caustics.png"} <= artifacts
