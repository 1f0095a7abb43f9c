"""The plugin seams: every config group composes and builds, every registry key instantiates, and
an operator and a non-iterative solver defined only in the test suite (examples/plugins/)
run through sfc-simulate and sfc-reconstruct, registered the way a third-party package registers
its plugins (entry points) and configured through Hydra's search path."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from mlflow.tracking import MlflowClient
from omegaconf import OmegaConf

from framework.core.data import ReconstructionData
from framework.core.plugin_config import build_plugin
from framework.core.problem import HeightGrid, Problem
from framework.reconstruction.parts import Reconstruction
from framework.core.registry import KINDS, available, register
from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.imaging import ImagingOperator
from operators.scene import Receiver, Scene
from examples.plugins.exact_step_solver import ExactStepSolver
from examples.plugins.shadow_operator import ShadowOperator

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
SMALL = ["photons=60000", "receiver.resolution=64", "height_field.resolution=32"]
# Each option of each group of conf/reconstruct.yaml, with what it needs beside it.
NEEDS = {("solver", "gradient_descent"): ["experiment=m1"], ("solver", "gradient_descent_paper"): ["experiment=m1"],
         ("solver", "landweber_wavelet"): ["experiment=m3v1"], ("solver", "schwartzburg"): ["experiment=schwartzburg"],
         ("data", "file"): ["data.image=caustic.npy"],
         ("data", "photo"): ["data.photo=photo.npy", "data.corners=[[0,63],[63,63],[63,0],[0,0]]"],
         ("initial", "file"): ["initial.path=start.npy"], ("experiment", "design"): ["data.printed=start.npy"],
         ("initial", "design"): ["data.printed=start.npy"],
         ("solver", "tracks"): ["experiment=tracks", "data.printed=start.npy"],
         ("experiment", "tracks"): ["data.printed=start.npy"]}
GROUPS = [
    "scene",
    "operator",
    "reconstruct_operator",
    "data",
    "solver",
    "stopping",
    "tracking",
    "experiment",
    "initial",
]
OPTIONS = [(group, path.stem) for group in GROUPS for path in sorted((CONF / group).glob("*.yaml"))]


@pytest.mark.parametrize("group, option", OPTIONS, ids=[f"{g}={o}" for g, o in OPTIONS])
def test_every_config_group_option_composes_and_builds(tmp_path, group, option):
    choice = f"operator={option}" if group == "reconstruct_operator" else f"{group}={option}"
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = OmegaConf.to_container(
            compose("reconstruct", overrides=[*SMALL, choice, *NEEDS.get((group, option), [])]), resolve=True
        )
    np.save(tmp_path / "start.npy", np.zeros((32, 32)))
    parts = Reconstruction.from_config(cfg, tmp_path)  # every plugin built and checked, nothing rendered
    channels = len(cfg["wavelengths"]) * len(cfg["data"].get("shots") or [None])  # a stack: every shot's
    assert callable(parts.start) and parts.operator.output_shape == (channels, 64, 64)
    assert parts.max_iter >= 1 and [type(rule).__name__ for rule in parts.fresh_stopping()] == [
        {"morozov": "MorozovStopping", "stagnation": "StagnationStopping"}[name] for name in cfg.get("stopping") or {}]


def small_problem() -> Problem:
    operator = ShadowOperator(1, 16, 1.0, 1, 1.0)
    target = operator.render(torch.rand(8, 8, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) * 0.1)
    data = ReconstructionData(target=target, mask=torch.ones(8, 8, dtype=torch.bool), volume=0.01, delta=0.05)
    return Problem(operator, data, HeightGrid(8, 1.0, 0.1), Scene(receiver=Receiver(resolution=16)))


STEP = {"name": "constant", "tau": 1e-3}
def _camera() -> ImagingOperator:
    """A camera around a small height-field operator: what joint calibration fits the gain of."""
    scene = Scene(receiver=Receiver(resolution=16))
    return ImagingOperator(lambda for_scene: CausticOperator(for_scene, OperatorSettings(photons=4096)), scene)


# Every built-in registry key with a small config (and the arguments the framework supplies).
MINIMAL = {
    ("operator", "height_field"): ({}, {"scene": Scene(receiver=Receiver(resolution=16)), "photons": 100, "seed": 0}),
    ("operator", "mesh_scene"): (
        {
            "elements": [
                {
                    "name": "lens",
                    "shape": "lens",
                    "position": [0, 0, 1.15],
                    "params": {"radius": 1.0, "thickness": 0.3, "front_radius": 4.0, "back_radius": 4.0},
                }
            ]
        },
        {"scene": Scene(receiver=Receiver(resolution=16)), "photons": 100, "seed": 0},
    ),
    ("solver", "gradient_descent"): ({"step_size": STEP}, {}),
    ("solver", "landweber_pixel"): (
        {"step_size": STEP, "regularizers": {"l1_bounds": {}}, "post_steps": {"volume_v1": {}}},
        {},
    ),
    ("solver", "landweber_wavelet"): (
        {
            "step_size": STEP,
            "wavelet_regularizer": {"name": "l1_wavelet", "levels": 1},
            "preconditioner": {"name": "sobolev"},
        },
        {},
    ),
    ("solver", "schwartzburg"): ({"outer_tolerance": 0.5}, {}),
    ("design", "schwartzburg"): ({"outer_tolerance": 0.5}, {}),
    ("design", "design_lbfgs"): ({}, {}),
    ("design", "design_adam"): ({"lr": 1e-3}, {}),
    ("solver", "gauss_newton"): (
        {
            "step_size": STEP,
            "regularizers": {"l1_bounds": {}},
            "post_steps": {"volume_hold": {}},
            "gauss_newton": {"cg_iterations": 2},
        },
        {},
    ),
    ("regularizer", "bounds"): ({}, {}),
    ("regularizer", "l1_bounds"): ({}, {}),
    ("regularizer", "l1_pixel"): ({}, {}),
    ("regularizer", "l1_wavelet"): ({}, {}),
    ("regularizer", "volume_v2"): ({}, {}),
    ("regularizer", "l1_design"): ({}, {}),
    ("post_step", "volume_v1"): ({}, {}),
    ("post_step", "volume_hold"): ({}, {}),
    ("step_size", "constant"): ({"tau": 0.1}, {}),
    ("step_size", "backtracking"): ({"tau": 0.1}, {}),
    ("preconditioner", "sobolev"): ({}, {}),
    ("stopping", "morozov"): ({"tau_dis": 1.05}, {}),
    ("stopping", "stagnation"): ({}, {}),
    ("data", "synthetic"): ({}, {}),
    ("data", "file"): ({"image": "caustic.npy"}, {}),
    ("data", "photo"): ({"photo": "photo.npy", "corners": [[0, 63], [63, 63], [63, 0], [0, 0]]}, {}),
    ("data", "stack"): ({"shots": [{"offset": 0.0}, {"offset": 0.15}]}, {}),
    ("initial", "zero"): ({}, {}),
    ("initial", "design"): ({}, {}),
    ("initial", "file"): ({"path": "start.npy"}, {}),
    ("initial", "transport"): ({}, {}),
    ("initial", "auto"): ({"candidates": {"zero": {}, "transport": {}}}, {}),
    ("solver", "parametric"): ({"representation": {"name": "pixels"}}, {}),
    ("representation", "pixels"): ({}, {}),
    ("representation", "wavelets"): ({"levels": 1}, {}),
    ("representation", "tracks"): ({}, {}),
    ("stage", "shots"): ({}, {"cfg": {}}),
    ("stage", "ambiguity"): ({}, {"cfg": {}}),
    ("stage", "tracks"): ({}, {"cfg": {}}),
    ("stage", "defects"): ({}, {"cfg": {}}),
    ("tracker", "mlflow"): ({"experiment": "seams"}, {}),
    ("calibration", "joint"): ({"settings": {"params": ["gain"]}}, {"operator": _camera()}),
}


def test_every_registry_key_is_listed_here():
    assert {(kind, name) for kind in KINDS for name in available(kind)} == set(MINIMAL)


@pytest.mark.parametrize("kind, name", sorted(MINIMAL), ids=[f"{k}/{n}" for k, n in sorted(MINIMAL)])
def test_every_registry_key_instantiates(kind, name):
    params, supplied = MINIMAL[(kind, name)]
    plugin = build_plugin(kind, name, params, kind, **supplied)
    if kind in ("solver", "design"):  # a builder: the solver itself runs two iterations on a small problem
        problem = small_problem()
        result = plugin(problem, torch.zeros(8, 8, dtype=torch.float64)).run(2)
        assert result.iterations == 2 and result.history[-1].rel_discrepancy < 1.0
    elif kind == "operator":
        assert plugin.render(torch.zeros(8, 8, dtype=plugin.dtype)).shape == plugin.output_shape
    else:
        assert plugin is not None


def test_register_adds_a_plugin_in_process_and_refuses_a_taken_name(own_registrations):
    register("solver", "exact_step_in_process")(ExactStepSolver)
    make = build_plugin("solver", "exact_step_in_process", {}, "solver")
    problem = small_problem()
    result = make(problem, torch.zeros(8, 8, dtype=torch.float64)).run(5)
    assert result.iterations == 1 and result.stopped_by == "solver" and result.accepted
    assert result.history[-1].rel_discrepancy < 1e-12  # noise-free data: one exact step fits it
    with pytest.raises(ValueError, match="registered twice"):
        register("solver", "landweber_pixel")(ExactStepSolver)


def _plugin_env(tmp_path: Path) -> dict[str, str]:
    """An environment in which the test plugins are installed as a package's entry points."""
    dist = tmp_path / "site" / "sfc_test_plugins-0.1.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: sfc-test-plugins\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(
        "[shape_from_caustics.operator]\nshadow = examples.plugins.shadow_operator:ShadowOperator\n\n"
        "[shape_from_caustics.solver]\nexact_step = examples.plugins.exact_step_solver:ExactStepSolver\n\n"
        "[shape_from_caustics.initial]\nmask_mean = examples.plugins.mask_mean_start:MaskMeanStart\n\n"
        "[shape_from_caustics.stopping]\nsmall_change = examples.plugins.small_change_stopping:SmallChangeStopping\n\n"
        "[shape_from_caustics.data]\nnpz = examples.plugins.npz_data:NpzData\n\n"
        "[shape_from_caustics.regularizer]\nl2_pixel = examples.plugins.l2_regularizer:PixelL2\n")
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path / "site"), str(ROOT)])}


def _run_app(app: str, args: list[str], env: dict[str, str], cwd: Path) -> str:
    search_path = f"hydra.searchpath=[file://{ROOT / 'examples' / 'plugins' / 'conf'}]"
    done = subprocess.run([sys.executable, "-m", f"experiments.{app}", search_path, *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


@pytest.mark.slow
def test_the_test_suites_operator_solver_start_and_stopping_rule_run_through_both_apps(tmp_path):
    env = _plugin_env(tmp_path)
    scene = ["scene=bump", "height_field.resolution=16", "receiver.resolution=32", "operator=shadow"]

    out = _run_app("simulate", [*scene, f"hydra.run.dir={tmp_path / 'sim'}"], env, tmp_path)
    heights = np.load(tmp_path / "sim" / "heights.npy")
    caustic = np.load(tmp_path / "sim" / "caustic.npy")
    expected = 1.0 + 2.0 * np.kron(heights, np.ones((2, 2)))  # gain 2 (examples/plugins/conf/operator/shadow.yaml)
    np.testing.assert_allclose(caustic[0], expected, rtol=1e-6)
    assert (tmp_path / "sim" / "height_and_caustic.png").is_file() and "power on the receiver" in out

    run_dir, store = tmp_path / "rec", tmp_path / "mlruns"
    # with the test suite's start and stopping rule (one exact step is the least-squares fit from any start)
    _run_app("reconstruct", [*scene, "solver=exact_step", "~experiment", "+method=exact_step", "data.delta=0.002",
                             "data.reference_resolution=64", "initial=mask_mean", "stopping=small_change",
                             f"hydra.run.dir={run_dir}", f"tracking.store_dir={store}"], env, tmp_path)
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["start"] == "mask_mean" and metrics["start_height"] > 0
    # One step is the least-squares fit. Noise of norm delta |b| spread over the n^2 pixels: the
    # residual keeps the 3/4 of it that is not constant on the 2 x 2 squares, and each height
    # sample averages 4 pixels, divided by the gain 2: |d - d_true| = delta |b| / (4 * 2).
    delta, clean = 0.002, expected
    assert metrics["iterations"] == 1 and metrics["stopped_by"] in ("solver", "MorozovStopping")
    assert metrics["rel_discrepancy"] == pytest.approx(np.sqrt(0.75) * delta, rel=0.1)
    predicted = delta * np.linalg.norm(clean) / (4 * 2) / np.linalg.norm(heights)
    assert metrics["rel_error_d"] == pytest.approx(predicted, rel=0.15), (metrics["rel_error_d"], predicted)
    for name in ("heights.png", "centre_slice.png", "caustics.png", "convergence.png", "height_field.npy"):
        assert (run_dir / name).is_file(), name
    client = MlflowClient(tracking_uri=f"sqlite:///{store / 'mlflow.db'}")
    (run,) = client.search_runs([client.get_experiment_by_name("shape-from-caustics").experiment_id])
    assert run.info.status == "FINISHED"
    assert run.data.tags["operator"] == "shadow" and run.data.tags["solver"] == "exact_step"
    assert run.data.params["operator.gain"] == "2.0"
    assert len(client.get_metric_history(run.info.run_id, "rel_discrepancy")) >= 1
    assert {"heights.png", "metrics.json"} <= {a.path for a in client.list_artifacts(run.info.run_id)}

    # the example data source: the simulated caustic and its printed area in one archive, fitted exactly
    np.savez(tmp_path / "caustic.npz", caustic=caustic, mask=heights > 1e-3)
    npz_dir = tmp_path / "npz"
    _run_app("reconstruct", [*scene, "solver=exact_step", "~experiment", "+method=exact_step", "data=npz",
                             f"data.path={tmp_path / 'caustic.npz'}", "data.delta=0.01", "initial=zero",
                             "stopping=small_change", f"hydra.run.dir={npz_dir}", f"tracking.store_dir={store}"], env,
             tmp_path)
    metrics = json.loads((npz_dir / "metrics.json").read_text())
    assert metrics["iterations"] == 1 and metrics["rel_discrepancy"] < 1e-9


@pytest.mark.slow
def test_the_example_figure_script_sweeps_collects_and_plots(tmp_path):
    out = tmp_path / "figures"
    done = subprocess.run([sys.executable, "-m", "examples.plugins.figure_gain", "--store", str(tmp_path / "mlruns"),
                           "--out", str(out), "--overrides", f"hydra.sweep.dir={tmp_path / 'sweep'}"],
                          cwd=tmp_path, env=_plugin_env(tmp_path), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    rows = [line.split("|") for line in (out / "shadow_gain.md").read_text().splitlines()[2:]]
    assert [float(row[1]) for row in rows] == [1.0, 4.0]
    errors = [float(row[3]) for row in rows]
    assert errors[0] > errors[1] > 0  # a brighter shadow of the same noise level: a closer fit
    assert (out / "shadow_gain.png").stat().st_size > 1000
