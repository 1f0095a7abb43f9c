import json
import subprocess
import time

import pytest
import torch

from framework.core.callbacks import GroundTruthError
from framework.core.truth import GroundTruth
from framework.reconstruction.stopping import MorozovStopping
from framework.core.data import ReconstructionData
from framework.reconstruction.solvers import GradientDescent
from framework.tracking.mlflow_tracker import (
    EXPERIMENT_KIND,
    EXPERIMENT_KIND_TAG,
    MlflowTracker,
    code_version_tags,
    flatten_params,
)
from framework.tracking.tracking_dataset import data_dataset
from framework.tracking.tracking_target import check_tracking_server
from tests.framework.toy import DTYPE, make_problem

mlflow = pytest.importorskip("mlflow")
from mlflow.tracking import MlflowClient  # noqa: E402


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    return tmp_path_factory.mktemp("mlflow")


def _client(store):
    return MlflowClient(tracking_uri=f"sqlite:///{store.resolve() / 'mlflow.db'}")


def test_flatten_params_joins_keys_and_truncates_values():
    flat = flatten_params({"solver": {"name": "landweber_pixel", "step": {"tau": 0.1}}, "seeds": [1, 2],
                           "empty": {}, "long": "x" * 7000})
    assert flat["solver.name"] == "landweber_pixel" and flat["solver.step.tau"] == "0.1"
    assert flat["seeds"] == "[1, 2]" and flat["empty"] == "{}"
    assert len(flat["long"]) == 6000 and flat["long"].endswith("[truncated]")
    with pytest.raises(ValueError, match="250"):
        flatten_params({"k" * 300: 1})
    with pytest.raises(ValueError, match="mapping"):
        flatten_params([1, 2])


def test_run_is_found_again_with_params_metric_history_and_artefact(store, tmp_path):
    data, op, A, b, d_true, L = make_problem()
    solver = GradientDescent(data, torch.zeros(8, 8, dtype=DTYPE), 1.0 / L)
    (tmp_path / "run_dir").mkdir()
    (tmp_path / "run_dir" / "reconstruction.pt").write_bytes(b"fake")
    params = {"solver": {"name": "gradient_descent", "tau": 1.0 / L}, "scene": {"m": 8}}
    with MlflowTracker("toy", run_name="m1", store_dir=store, params=params,
                       tags={"method": "M1", "scene": "toy"}, sweep_id="sweep-1") as tracker:
        result = solver.run(6, [GroundTruthError(GroundTruth(d_true), 0.1), tracker.metrics_callback()])
        tracker.log_artifacts(tmp_path / "run_dir")
    client = _client(store)
    run = client.get_run(tracker.run_id)
    assert run.info.status == "FINISHED"
    assert run.data.params["solver.name"] == "gradient_descent" and run.data.params["scene.m"] == "8"
    assert run.data.tags["method"] == "M1" and run.data.tags["sweep_id"] == "sweep-1"
    assert run.data.tags["stopped_by"] == "max_iter"
    history = client.get_metric_history(tracker.run_id, "rel_discrepancy")
    assert sorted(m.step for m in history) == [1, 2, 3, 4, 5, 6]
    by_step = {m.step: m.value for m in history}
    assert by_step[6] == pytest.approx(result.history[-1].rel_discrepancy)
    assert len(client.get_metric_history(tracker.run_id, "rel_error")) == 6
    assert [a.path for a in client.list_artifacts(tracker.run_id)] == ["reconstruction.pt"]
    found = client.search_runs([tracker.experiment_id], "tags.sweep_id = 'sweep-1'")
    assert [r.info.run_id for r in found] == [tracker.run_id]


def test_exception_ends_run_failed_and_is_reraised(store):
    with pytest.raises(RuntimeError, match="boom"):
        with MlflowTracker("toy", store_dir=store) as tracker:
            raise RuntimeError("boom")
    run = _client(store).get_run(tracker.run_id)
    assert run.info.status == "FAILED" and "boom" in run.data.tags["error"]


def test_keyboard_interrupt_ends_run_killed_and_is_reraised(store):
    data, *_, L = make_problem()
    solver = GradientDescent(data, torch.zeros(8, 8, dtype=DTYPE), 1.0 / L)

    class Interrupt(MorozovStopping):
        def on_iteration(self, solver, record):
            if record.iteration == 2:
                raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        with MlflowTracker("toy", store_dir=store) as tracker:
            solver.run(10, [tracker.metrics_callback(), Interrupt(0.05, 1.1)])
    client = _client(store)
    assert client.get_run(tracker.run_id).info.status == "KILLED"
    # the interrupt (order 0) fires before the MLflow callback (order 50) logs iteration 2
    assert [m.step for m in client.get_metric_history(tracker.run_id, "objective")] == [1]


def test_nested_child_run_points_to_its_parent(store):
    with MlflowTracker("toy", run_name="sweep", store_dir=store) as parent:
        with parent.child(run_name="job-0", tags={"method": "M2V1"}) as child:
            child.log_metrics({"x": 1.0}, step=0)
    run = _client(store).get_run(child.run_id)
    assert run.data.tags["mlflow.parentRunId"] == parent.run_id and run.info.status == "FINISHED"


def test_tracker_without_active_run_is_an_error(store):
    with pytest.raises(RuntimeError, match="no active run"):
        MlflowTracker("toy", store_dir=store).log_metrics({"x": 1.0})
    with pytest.raises(ValueError, match="experiment"):
        MlflowTracker("")


def test_experiments_are_custom_model_experiments_new_or_existing(store):
    client = _client(store)
    with MlflowTracker("kind-new", store_dir=store) as tracker:
        pass
    assert client.get_experiment(tracker.experiment_id).tags[EXPERIMENT_KIND_TAG] == EXPERIMENT_KIND
    old = client.create_experiment("kind-old")  # as made before the tag, or by another tool
    with MlflowTracker("kind-old", store_dir=store):
        pass
    assert client.get_experiment(old).tags[EXPERIMENT_KIND_TAG] == EXPERIMENT_KIND


def test_runs_carry_the_code_version(store):
    with MlflowTracker("toy", store_dir=store) as tracker:
        pass
    tags = _client(store).get_run(tracker.run_id).data.tags
    assert len(tags["mlflow.source.git.commit"]) == 40 and tags["git_dirty"] in {"true", "false"}
    assert tags["mlflow.source.name"] and tags["mlflow.source.type"] == "LOCAL"


def test_code_version_is_unknown_outside_a_repository_or_without_git(tmp_path, monkeypatch):
    outside = code_version_tags(tmp_path)
    assert outside["mlflow.source.git.commit"] == "unknown" and outside["git_dirty"] == "unknown"

    def no_git(*args, **kwargs):
        raise FileNotFoundError("git")

    monkeypatch.setattr(subprocess, "run", no_git)
    assert code_version_tags()["mlflow.source.git.commit"] == "unknown"


def _data(seed: int = 0, truth: bool = True, source: str | None = None) -> ReconstructionData:
    target = torch.rand(1, 8, 8, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    mask = torch.ones(4, 4, dtype=torch.bool)
    return ReconstructionData(target, mask, volume=0.01, delta=0.05, source=source,
                              ground_truth=GroundTruth(torch.zeros(4, 4, dtype=torch.float64)) if truth else None)


SYNTHETIC = {"data": {"name": "synthetic", "delta": 0.05}, "height_field": {"shape": "bump", "path": None}, "seed": 3}


def test_synthetic_data_are_named_by_scene_described_by_seed_and_noise_and_digested():
    dataset = data_dataset(_data(), SYNTHETIC)
    assert dataset.name == "synthetic:bump" and dataset.source.to_dict()["tags"]["seed"] == 3
    assert dataset.digest == data_dataset(_data(), SYNTHETIC).digest
    assert dataset.digest != data_dataset(_data(), {**SYNTHETIC, "seed": 4}).digest
    assert dataset.digest != data_dataset(_data(seed=1), SYNTHETIC).digest


def test_measured_data_name_their_file_and_log_as_the_runs_input(store, tmp_path):
    cfg = {"data": {"name": "file", "image": "caustic.npy", "mask": "mask.npy", "volume": 0.01}}
    measured = _data(truth=False, source=str(tmp_path.resolve() / "caustic.npy"))  # as data sources say
    with MlflowTracker("toy", store_dir=store) as tracker:
        tracker.log_data(measured, cfg)
    (logged,) = _client(store).get_run(tracker.run_id).inputs.dataset_inputs
    assert logged.dataset.name == "caustic.npy" and logged.dataset.source_type == "local"
    assert json.loads(logged.dataset.source)["uri"] == str(tmp_path.resolve() / "caustic.npy")
    assert logged.dataset.digest == data_dataset(measured, cfg).digest
    assert set(json.loads(logged.dataset.profile)["features_shape"]) == {"caustic", "mask", "volume"}
    assert [(t.key, t.value) for t in logged.tags] == [("mlflow.data.context", "reconstruction")]


def test_an_unreachable_tracking_server_is_refused_in_one_line():
    url = "http://127.0.0.1:9"  # the discard port: nothing answers
    start = time.perf_counter()
    with pytest.raises(ValueError, match=rf"tracking.uri={url} does not answer.*tracking.uri=null") as refused:
        with MlflowTracker("toy", tracking_uri=url):
            pass
    assert time.perf_counter() - start < 10 and "\n" not in str(refused.value)
    check_tracking_server("sqlite:///elsewhere.db")  # not a server: nothing to check


def test_a_new_store_is_a_copy_of_the_empty_store_and_keeps_defaults_artefacts_inside(tmp_path, monkeypatch):
    """A new local store is copied from the empty store of this MLflow version in the cache
    (built there once): MLflow opens it and logs into it as into a store it built, its Default
    experiment's artefacts lie in the store, and the cached file is left as it was."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    template = tmp_path / "cache" / "shape-from-caustics" / f"mlflow-{mlflow.__version__}-empty.db"
    for name in ("first", "second"):
        with MlflowTracker("toy", store_dir=tmp_path / name, params={"a": 1}) as tracker:
            tracker.log_metrics({"rel_discrepancy": 0.5}, step=1)
        client = _client(tmp_path / name)
        assert client.get_run(tracker.run_id).data.metrics["rel_discrepancy"] == 0.5
        default = client.get_experiment("0")
        assert default.name == "Default"
        assert default.artifact_location == f"{(tmp_path / name / 'artifacts').as_uri()}/0"
        assert template.exists()
    assert [e.name for e in MlflowClient(tracking_uri=f"sqlite:///{template}").search_experiments()] == ["Default"]
