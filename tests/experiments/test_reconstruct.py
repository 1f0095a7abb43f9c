"""End-to-end reconstructions with the real operator on small problems."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
import torch
from mlflow.tracking import MlflowClient

from framework.core.callbacks import MetricsHistory
from framework.core.problem import Problem
from framework.reconstruction.reconstruction import CHECKPOINT, run_reconstruction
from framework.reconstruction.parts import Reconstruction, build_start
from framework.scene.scene_config import build_heights
from framework.core.contracts.start import StartRequest
from operators.heightfield.operator import CausticOperator
from tests.experiments.conftest import SMALL, compose_reconstruct

# A bump that focuses light visibly at 64 x 64 (a weak one is hidden by the noise: Morozov stops at
# d = 0), with 1% noise and a step suited to its gentle slopes.
BUMP = ["scene=bump", "height_field.params.sigma=0.15", "height_field.params.height=0.05", "data.delta=0.01",
        "solver.step_size.tau=1e-3"]


@pytest.mark.slow
def test_smooth_bump_is_recovered_and_the_run_is_tracked(tmp_path):
    cfg = compose_reconstruct([*SMALL, *BUMP, "solver.max_iter=40"], tmp_path)
    metrics = run_reconstruction(cfg, tmp_path / "run", tmp_path)
    # d = 0 has rel_error_d = 1 and rel_error 0.058; 40 iterations bring back most of the bump.
    assert metrics["rel_error_d"] < 0.5, metrics
    assert metrics["rel_error"] < 0.03, metrics
    heights = np.load(tmp_path / "run" / "height_field.npy")
    assert heights.shape == (32, 32) and heights.min() >= 0.0
    saved = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert saved["iterations"] == metrics["iterations"] and saved["stop_reason"]
    for name in ("heights.png", "centre_slice.png", "caustics.png", "convergence.png", CHECKPOINT):
        assert (tmp_path / "run" / name).is_file(), name

    client = MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'mlruns' / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("shape-from-caustics")
    (run,) = client.search_runs([experiment.experiment_id])
    assert run.info.status == "FINISHED"
    assert run.data.tags["method"] == "M2V1" and run.data.tags["scene"] == "bump"
    assert run.data.params["solver.name"] == "landweber_pixel"
    history = client.get_metric_history(run.info.run_id, "rel_discrepancy")
    assert len(history) >= metrics["iterations"]
    artifacts = {a.path for a in client.list_artifacts(run.info.run_id)}
    assert {"height_field.npy", "metrics.json"} <= artifacts


@pytest.mark.slow
def test_resume_continues_an_interrupted_run_to_the_same_result(tmp_path):
    base = [*SMALL, *BUMP]
    full = run_reconstruction(compose_reconstruct([*base, "solver.max_iter=6"], tmp_path),
                              tmp_path / "full", tmp_path)
    run_reconstruction(compose_reconstruct([*base, "solver.max_iter=4"], tmp_path), tmp_path / "part", tmp_path)
    resumed = run_reconstruction(
        compose_reconstruct([*base, "solver.max_iter=6", f"resume={tmp_path / 'part' / CHECKPOINT}"], tmp_path),
        tmp_path / "resumed", tmp_path)
    assert resumed["iterations"] == full["iterations"] == 6
    assert np.array_equal(np.load(tmp_path / "full" / "height_field.npy"),
                          np.load(tmp_path / "resumed" / "height_field.npy"))


def test_starts_from_zero_design_or_file(tmp_path):
    cfg = compose_reconstruct([*SMALL, *BUMP], tmp_path)
    parts = Reconstruction.from_config(cfg, tmp_path)
    design = 0.8 * build_heights(cfg)  # a design the data carry (the print is the configured bump)
    data = replace(parts.data_source.load(parts.data_request(tmp_path)).without_truth(), design=design)
    problem = Problem(parts.operator, data, parts.grid, parts.scene)

    def start(spec: dict) -> torch.Tensor:
        return build_start(spec)(StartRequest(problem, tmp_path)).d

    assert torch.equal(start({"name": "zero"}), torch.zeros(32, 32))
    half = start({"name": "design", "scale": 0.5}).double()
    assert torch.allclose(half, 0.5 * design, atol=1e-7) and float(half.max()) > 0.015
    with pytest.raises(ValueError, match="these data carry no design of the print"):
        build_start({"name": "design"})(StartRequest(replace(problem, data=replace(data, design=None)), tmp_path))
    np.save(tmp_path / "start.npy", np.full((16, 16), 0.01))
    from_file = start({"name": "file", "path": "start.npy", "scale": 2.0}).double()
    assert from_file.shape == (32, 32) and torch.allclose(from_file, torch.full((32, 32), 0.02, dtype=torch.float64))
    with pytest.raises(FileNotFoundError, match="missing.npy"):
        start({"name": "file", "path": "missing.npy"})
    with pytest.raises(ValueError, match="initial.scale=-1"):
        build_start({"name": "design", "scale": -1})
    with pytest.raises(ValueError, match="initial.path=None"):
        build_start({"name": "file"})
    with pytest.raises(ValueError, match="initial=file initial.path="):
        build_start("start.npy")


FLAT_FIRST = ["initial=auto", "~initial.candidates", "+initial.candidates={zero: {}, transport: {}}"]


@pytest.mark.slow
def test_auto_tries_the_next_start_only_when_a_run_ends_short_of_the_noise_level(tmp_path):
    base = [*SMALL, *BUMP, *FLAT_FIRST, "solver.max_iter=3"]
    # Two iterations cannot reach a 1% noise level from flat glass: the transport start runs next.
    metrics = run_reconstruction(compose_reconstruct(base, tmp_path), tmp_path / "both", tmp_path)
    assert metrics["start_zero_iterations"] == 3 and metrics["start_zero_reached_noise_level"] == 0.0
    ends = {name: (metrics[f"start_{name}_reached_noise_level"], -metrics[f"start_{name}_rel_discrepancy"])
            for name in ("zero", "transport")}
    assert metrics["start"] == max(ends, key=ends.get)
    assert metrics["rel_discrepancy"] == pytest.approx(metrics[f"start_{metrics['start']}_rel_discrepancy"], rel=1e-6)
    assert metrics["volume_ratio"] == pytest.approx(float(np.load(tmp_path / "both" / "height_field.npy").sum())
                                                    / float(np.load(tmp_path / "both" / "ground_truth.npy").sum()))
    # Flat glass that meets Morozov's rule (here a loose one, no volume band) is kept, and the
    # transport never computed.
    loose = run_reconstruction(compose_reconstruct([*base, "experiment=m2v0", "stopping.morozov.tau_dis=50"], tmp_path),
                               tmp_path / "flat", tmp_path)
    assert loose["start"] == "zero" and loose["start_zero_reached_noise_level"] == 1.0
    assert "start_transport_rel_discrepancy" not in loose and loose["iterations"] == 1


@pytest.mark.slow
def test_an_auto_run_interrupted_in_its_second_start_resumes_there(tmp_path, monkeypatch):
    base = [*SMALL, *BUMP, *FLAT_FIRST, "solver.max_iter=4", "~stopping.morozov"]  # neither start is accepted
    full = run_reconstruction(compose_reconstruct(base, tmp_path), tmp_path / "full", tmp_path)
    assert full["start_zero_iterations"] == 4 and full["start_transport_iterations"] == 4
    calls = {"n": 0}
    original = MetricsHistory.on_iteration

    def interrupt(self, solver, record):  # the 7th iteration overall: the transport run's third
        calls["n"] += 1
        if calls["n"] == 7:
            raise KeyboardInterrupt
        return original(self, solver, record)

    monkeypatch.setattr(MetricsHistory, "on_iteration", interrupt)
    with pytest.raises(KeyboardInterrupt):
        run_reconstruction(compose_reconstruct(base, tmp_path), tmp_path / "cut", tmp_path)
    monkeypatch.setattr(MetricsHistory, "on_iteration", original)
    resumed = run_reconstruction(compose_reconstruct(base, tmp_path), tmp_path / "cut", tmp_path)  # resume: auto
    assert resumed["start"] == full["start"] and resumed["start_zero_iterations"] == 4
    assert np.array_equal(
        np.load(tmp_path / "full" / "height_field.npy"), np.load(tmp_path / "cut" / "height_field.npy")
    )


@pytest.mark.slow
def test_a_start_from_half_the_design_beats_the_flat_start(tmp_path):
    # The print is the configured bump 10% taller, so the design (the configured bump) is not the answer.
    # The starts alone: the held volume would lift half the design to its volume in the first step.
    np.save(tmp_path / "printed.npy", 1.1 * build_heights(compose_reconstruct([*SMALL, *BUMP], tmp_path)).numpy())
    base = [*SMALL, *BUMP, "solver.max_iter=6", "~solver.post_steps.volume_hold", "data.printed=printed.npy",
            "defects.enabled=off"]
    flat = run_reconstruction(compose_reconstruct(base, tmp_path), tmp_path / "flat", tmp_path)
    half = run_reconstruction(compose_reconstruct([*base, "initial=design", "initial.scale=0.5"], tmp_path),
                              tmp_path / "half", tmp_path)
    assert 0.5 < half["start_design_initial_rel_error_d"] < 0.6, half  # 1 - 0.5 / 1.1
    assert half["rel_error_d"] < 0.5 * flat["rel_error_d"], (half, flat)
    # Synthetic data of the configured heights carry no design: the design start is refused before the run.
    with pytest.raises(ValueError, match="initial=design reads the print's design"):
        run_reconstruction(compose_reconstruct([*SMALL, *BUMP, "initial=design"], tmp_path), tmp_path / "no", tmp_path)


@pytest.mark.slow
def test_a_coarse_level_brings_the_bump_the_fine_level_starts_from(tmp_path):
    """coarse_to_fine.levels=2: the bump solved on 16 x 16 heights (a 32 x 32 receiver) first; the
    32 x 32 run starts from it, far closer to the truth than flat glass (rel_error_d 1), at the
    finest preconditioner length (fine_levels_from: finest) though flat glass began the coarse level
    at the first."""
    cfg = compose_reconstruct([*SMALL, *BUMP, "solver.max_iter=30", "coarse_to_fine.levels=2",
                               "coarse_to_fine.coarsest=16"], tmp_path)
    metrics = run_reconstruction(cfg, tmp_path / "levels", tmp_path)
    assert 1 <= metrics["start_zero_level16_iterations"] <= 30, metrics
    assert metrics["start_zero_initial_rel_error_d"] < 0.7, metrics
    assert metrics["rel_error_d"] < 0.5, metrics
    history = torch.load(tmp_path / "levels" / "checkpoint.pt", weights_only=False)["solver_state"]["history"]
    lengths = cfg["solver"]["preconditioner"]["length"]
    assert min(lengths) < max(lengths)
    assert history[0]["extras"]["preconditioner_length"] == pytest.approx(min(lengths))


@pytest.mark.parametrize("experiment", ["m1", "m2v0", "m2v1", "m2v2", "m3v0", "m3v1", "m3v2"])
@pytest.mark.slow
def test_every_experiment_preset_runs_two_iterations(tmp_path, experiment):
    cfg = compose_reconstruct([*SMALL, f"experiment={experiment}", "solver.max_iter=2"], tmp_path)
    metrics = run_reconstruction(cfg, tmp_path / experiment, tmp_path)
    assert metrics["iterations"] == 2 and math.isfinite(metrics["rel_error"])
    assert metrics["method"] == experiment.upper()


@pytest.mark.slow
def test_the_papers_plain_iteration_runs_with_the_readme_overrides(tmp_path):
    # Hydra merges a dict override into the default step size: docs/method.md deletes it first.
    plain = ["solver.preconditioner=null", "~solver.step_size", "+solver.step_size={name: constant, tau: 2.5e-4}"]
    cfg = compose_reconstruct([*SMALL, *plain, "solver.max_iter=2"], tmp_path)
    assert cfg["solver"]["step_size"] == {"name": "constant", "tau": 2.5e-4}
    assert run_reconstruction(cfg, tmp_path / "plain", tmp_path)["iterations"] == 2


def test_measured_data_from_files(tmp_path):
    image = torch.rand(1, 64, 64).numpy() + 0.5
    np.save(tmp_path / "caustic.npy", image)
    mask = np.zeros((32, 32), dtype=np.uint8)
    mask[8:24, 8:24] = 1
    np.save(tmp_path / "mask.npy", mask)
    cfg = compose_reconstruct([*SMALL, "data=file", "data.image=caustic.npy", "data.mask=mask.npy",
                               "data.volume=0.01", "solver.max_iter=2"], tmp_path)
    metrics = run_reconstruction(cfg, tmp_path / "run", tmp_path)
    heights = np.load(tmp_path / "run" / "height_field.npy")
    assert metrics["iterations"] == 2 and "rel_error" not in metrics
    assert np.all(heights[mask == 0] == 0.0)


@pytest.mark.parametrize("overrides, error, message", [
    (["data=file"], ValueError, "data.image"),
    (["data=file", "data.image=missing.npy"], FileNotFoundError, "missing.npy"),
    (["data=file", "data.image=caustic.npy", "data.mask=small_mask.npy"], ValueError, "must match the height field"),
    (["data=file", "data.image=nan.npy"], ValueError, "NaN"),
    (["data.delta=0.0001", "data.reference=model"], ValueError, "intrinsic noise"),
    (["data.reference=paper"], ValueError, "data.reference=.paper."),
    (["data.delta=1.5"], ValueError, "data.delta=1.5"),
    (["experiment=m1", "+solver.regularizers.l1_pixel.alpha=0.1"], ValueError,
     "unknown key solver.regularizers; solver/gradient_descent takes: step_size, preconditioner"),
    (["+solver.regularizers.no_such_prior={}"], KeyError, "no_such_prior"),
    (["solver.step_size.name=adam"], KeyError, "unknown step_size plugin 'adam'"),
    (["solver.step_size.shrink=2"], ValueError, "shrink must lie in"),
    (["experiment=m1", "+solver.step_size.growth=0.5"], ValueError, "unknown key solver.step_size.growth"),
    (["+solver.pixel_step_ratio=2"], ValueError, "unknown key solver.pixel_step_ratio"),
    (["experiment=m3v1", "solver.pixel_step_ratio=0"], ValueError, "pixel_step_ratio"),
    (["+stopping.patience={}"], KeyError, "unknown stopping plugin 'patience'"),
    (["stopping.morozov.tau_dis=1.0"], ValueError, r"stopping.morozov.tau_dis=1.0 must be a number > 1"),
    (["operator.name=mesh"], KeyError, "unknown operator plugin 'mesh'"),
    (["data.name=camera"], KeyError, "unknown data plugin 'camera'"),
    (["data=photo"], ValueError, "data.photo"),
    (["data=photo", "data.photo=caustic.npy"], ValueError, "data.corners"),
    (["data=photo", "data.photo=photo.npy", "data.corners=[[1,60],[90,60],[60,2],[2,2]]"], ValueError,
     "outside the 64 x 64"),
    (["data=photo", "data.photo=photo.npy", "data.corners=[[2,60],[60,60],[2,2],[60,2]]"], ValueError,
     "self-intersecting"),
    (["units.mm_per_unit=0"], ValueError, "units.mm_per_unit=0"),
    (["screen.psf=lorentz"], ValueError, "screen.psf='lorentz'"),
    (["screen.psf=gaussian"], ValueError, "screen.sigma > 0"),
    (["calibration.params=[focus]"], ValueError, "calibration.params=\\['focus'\\]"),
    (["solver.preconditioner.length=-1"], ValueError, "length=-1"),
    (["solver.preconditioner.name=multigrid"], KeyError, "multigrid"),
    (["stopping.stagnation.patience=0"], ValueError, "patience=0"),
    (["coarse_to_fine.levels=0"], ValueError, "coarse_to_fine.levels=0"),
])
def test_bad_configuration_is_refused_clearly(tmp_path, overrides, error, message):
    np.save(tmp_path / "caustic.npy", np.ones((1, 64, 64)))
    np.save(tmp_path / "small_mask.npy", np.ones((16, 16)))
    np.save(tmp_path / "nan.npy", np.full((1, 64, 64), np.nan))
    np.save(tmp_path / "photo.npy", np.full((64, 64), 0.5))
    cfg = compose_reconstruct([*SMALL, *overrides, "solver.max_iter=1"], tmp_path)
    with pytest.raises(error, match=message):
        run_reconstruction(cfg, tmp_path / "run", tmp_path)


def test_stage_changes_come_from_the_records_whoever_asked_for_them():
    from framework.reconstruction.solvers.proximal_gradient import stage_changes
    from framework.reconstruction.solvers import IterationRecord

    def record(i, length):
        extras = {} if length is None else {"preconditioner_length": length}
        return IterationRecord(iteration=i, objective=1.0, data_fidelity=1.0, rel_discrepancy=0.1, step_size=0.1,
                               elapsed_s=0.0, extras=extras)

    lengths = [0.125, 0.125, 0.125, 0.0625, 0.0625, 0.03125]
    assert stage_changes([record(i + 1, v) for i, v in enumerate(lengths)]) == [3, 5]
    assert stage_changes([record(i + 1, None) for i in range(4)]) == []  # no preconditioner


@pytest.mark.slow
def test_the_app_refuses_a_bad_value_in_one_line(tmp_path):
    done = subprocess.run([sys.executable, "-m", "experiments.apps.reconstruct", *SMALL,
                           "stopping.stagnation.patience=0",
                           f"hydra.run.dir={tmp_path / 'run'}", f"tracking.store_dir={tmp_path / 'mlruns'}"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 1
    assert "Traceback" not in done.stderr  # above the message only MLflow's log of creating its store
    assert done.stderr.strip().splitlines()[-1] == (
        "error: patience=0 must be an integer >= 1 (iterations), e.g. 8; null disables the rule "
        "(SFC_TRACEBACK=1 shows the traceback)")


@pytest.mark.parametrize("overrides, message", [
    (["stopping.stagnation.patience=0"], "patience=0"),
    (["solver.step_size.name=adam"], "adam"),
    (["+solver.regularizers.no_such_prior={}"], "no_such_prior"),
    (["experiment=m1", "+solver.regularizers.l1_pixel.alpha=0.1"], "unknown key solver.regularizers"),
    (["experiment=m3v1", "~solver.wavelet_regularizer", "+solver.wavelet_regularizer={name: l1_pixel}"],
     "has no wavelet transform"),
    (["stopping.morozov.tau_dis=0.5"], "tau_dis"),
    (["initial=file", "initial.path=missing.npy"], "missing.npy"),
    (["initial=transport", "initial.reach=2"], "initial.reach=2"),
    (["initial=auto", "+initial.candidates.auto={}"], "may not contain auto"),
])
def test_bad_solver_configuration_fails_before_the_data_is_rendered(tmp_path, monkeypatch, overrides, message):
    def no_render(*args, **kwargs):
        raise AssertionError("rendered before the configuration was checked")

    monkeypatch.setattr(CausticOperator, "render", no_render)
    cfg = compose_reconstruct([*SMALL, *overrides, "solver.max_iter=1"], tmp_path)
    with pytest.raises((ValueError, KeyError, FileNotFoundError), match=message):
        run_reconstruction(cfg, tmp_path / "run", tmp_path)
    assert not (tmp_path / "mlruns").exists()  # no MLflow run was opened either
