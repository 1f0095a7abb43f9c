"""Caustic designs end to end on small problems: closed-form designs (flat glass, a focusing lens),
the target's energy, the files, MLflow, resuming, the baselines, bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import torch
import trimesh
from mlflow.tracking import MlflowClient
from PIL import Image

from framework.design.design_run import CHECKPOINT, run_design
from framework.design.design_setup import prepare_design
from operators.heightfield.catmull_rom import refinement_matrix
from tests.design.conftest import SMALL, compose_design
from tests.python_subprocess import ROOT

DISTANT = ["light.position=[0.0,0.0,1.0e4]"]  # a collimated light: the flat glass's caustic is uniform


def _png(path, picture: np.ndarray):
    Image.fromarray(picture.astype(np.uint8)).save(path)
    return str(path)


def test_a_uniform_target_under_a_distant_light_gives_flat_glass(tmp_path):
    target = _png(tmp_path / "uniform.png", np.full((32, 32), 200))
    cfg = compose_design([*SMALL, *DISTANT, f"target.image={target}", "seconds=8", "previews=[]"], tmp_path)
    result = run_design(cfg, tmp_path / "run")
    mm = 25.0
    # A ring design on this setup rises 5.6 mm; flat glass stays flat to a few micrometres.
    assert np.ptp(result.heights) * mm < 0.01, np.ptp(result.heights) * mm
    assert result.metrics["relative_l2"] < 0.02


@pytest.mark.slow
def test_a_single_spot_gives_a_lens_whose_focus_lies_on_the_screen(tmp_path):
    picture = np.zeros((32, 32))
    picture[15:17, 15:17] = 255  # the four centre pixels
    target = _png(tmp_path / "spot.png", picture)
    distance, index, thickness = 8.0, 1.457, 0.1
    cfg = compose_design([*SMALL, *DISTANT, f"target.image={target}", "target.width=0.5", f"receiver.z={-distance}",
                          "seconds=6", "previews=[]", "constraints.min_feature=null"], tmp_path)
    d = run_design(cfg, tmp_path / "run").heights
    m = d.shape[0]
    x = np.linspace(-1.0, 1.0, m)
    xx, yy = np.meshgrid(x, x)
    core = np.hypot(xx, yy) < 0.8
    # Near the axis the lens is the paraboloid d = c - r^2 / (2 R) (its vertex curvature; the r^4 term takes
    # the correction of spherical aberration farther out): a plano-convex lens of focal length f = R / (n - 1)
    # from its curved top, whose focus lies t / n less behind the flat bottom (t the thickness at the vertex).
    r2 = (xx ** 2 + yy ** 2)[core]
    design = np.column_stack([np.ones(core.sum()), r2, r2 ** 2])
    (c, k, q), *_ = np.linalg.lstsq(design, d[core], rcond=None)
    radius = -1.0 / (2.0 * k)
    back_focus = radius / (index - 1.0) - (thickness + c) / index
    assert back_focus == pytest.approx(distance, rel=0.05), back_focus
    fitted = design @ np.array([c, k, q])
    assert np.sqrt(np.mean((d[core] - fitted) ** 2)) < 0.02 * np.ptp(d[core])  # smooth, rotationally symmetric


def test_a_target_asking_more_light_than_reaches_the_screen_is_normalised_and_says_so(tmp_path):
    np.save(tmp_path / "bright.npy", np.full((32, 32), 50.0))  # W per scene unit^2: far more than arrives
    cfg = compose_design([*SMALL, f"target.image={tmp_path / 'bright.npy'}"], tmp_path)
    setup = prepare_design(cfg)
    flat = setup.operator.render(torch.zeros(32, 32, dtype=setup.operator.dtype)).double()
    assert float(setup.target.sum()) == pytest.approx(float(flat.sum()), rel=1e-9)
    (note,) = setup.notes
    assert "carries" in note and "scaled to it" in note
    ratio = float(note.split("carries ")[1].split("%")[0]) / 100
    assert ratio == pytest.approx(50.0 * 32 * 32 / float(flat.sum()), rel=1e-3)


@pytest.mark.slow
def test_a_design_writes_printable_files_logs_to_mlflow_and_resumes(tmp_path):
    # 2 s: far from where L-BFGS stops on this target (no descent at iteration 135), so the resumed run goes on
    cfg = compose_design([*SMALL, "target.image=ring", "seconds=2"], tmp_path)
    run = tmp_path / "run"
    first = run_design(cfg, run)
    for name in ("height_field.npy", "height_field_mm.png", "glass.stl", "glass.obj", "caustic.npy", "design.png",
                 "preview_0.5x.png", "preview_2x.png", "metrics.json", "verdict.txt", CHECKPOINT):
        assert (run / name).is_file(), name
    assert all(v == 1.0 for k, v in first.metrics.items() if k.startswith("holds_"))
    mesh = trimesh.load(run / "glass.stl")
    assert mesh.is_watertight
    mm, heights = 25.0, np.load(run / "height_field.npy")
    # The top samples the model's surface twice per spacing (mesh_refine 2), each fine cell split into
    # four triangles about the surface at its centre: area (sum of corners / 6 + centre / 3) per cell.
    m, refine = heights.shape[0], 2
    fine = refinement_matrix(m, 2 * refine) @ heights @ refinement_matrix(m, 2 * refine).T
    corners, centres = fine[::2, ::2], fine[1::2, 1::2]
    cell_sum = corners[:-1, :-1] + corners[:-1, 1:] + corners[1:, :-1] + corners[1:, 1:]
    area = (2.0 / ((m - 1) * refine)) ** 2
    expected = (2.0 * mm) ** 2 * 0.1 * mm + area * float((cell_sum / 6.0 + centres / 3.0).sum()) * mm ** 3
    assert mesh.volume == pytest.approx(expected, rel=1e-6)  # substrate + print, mm^3
    x = np.linspace(-1.0, 1.0, m)
    samples = (2.0 * mm) ** 2 * 0.1 * mm + np.trapezoid(np.trapezoid(heights, x), x) * mm ** 3
    assert mesh.volume == pytest.approx(samples, rel=1e-3)  # the samples' trapezoid rule, to the surface's bulge
    assert first.metrics["relative_l2"] < 0.5 and first.verdict[0].startswith("matches the target to")
    assert json.loads((run / "metrics.json").read_text())["iterations"] == first.metrics["iterations"]

    client = MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'mlruns' / 'mlflow.db'}")
    (mlrun,) = client.search_runs([client.get_experiment_by_name("caustic-design").experiment_id])
    assert mlrun.data.tags["method"] == "sfc" and mlrun.data.params["target.image"] == "ring"
    assert len(client.get_metric_history(mlrun.info.run_id, "rel_discrepancy")) == first.metrics["iterations"]

    more = first.metrics["design_seconds"] + 3.0  # three seconds beyond what the first run spent, however loaded
    again = run_design(compose_design([*SMALL, "target.image=ring", f"seconds={more:.2f}"], tmp_path), run)
    assert again.metrics["iterations"] > first.metrics["iterations"]  # continued from the checkpoint
    assert again.metrics["start_seconds"] == pytest.approx(first.metrics["start_seconds"])


@pytest.mark.slow
@pytest.mark.parametrize("method", ["adam", "schwartzburg"])
def test_the_baselines_design_printable_glass(tmp_path, method):
    cfg = compose_design([*[o for o in SMALL if not o.startswith("design_method.")], f"design_method={method}",
                          "target.image=ring", "seconds=5", "previews=[]"], tmp_path)
    result = run_design(cfg, tmp_path / "run")
    assert all(v == 1.0 for k, v in result.metrics.items() if k.startswith("holds_"))
    assert result.metrics["relative_l2"] < 1.0 and result.metrics["iterations"] >= 1


@pytest.mark.parametrize("method", ["sfc", "schwartzburg"])
def test_a_transport_cut_short_by_the_time_budget_says_so(tmp_path, method):
    # A budget of 1 ms ends the transport's Newton before its first step, in the start (sfc) or in
    # the first outer iteration (schwartzburg); the run still writes a printable design.
    small = [o for o in SMALL if method == "sfc" or not o.startswith("design_method.")]
    cfg = compose_design([f"design_method={method}", *small, "target.image=ring", "seconds=0.001", "previews=[]"],
                         tmp_path)
    result = run_design(cfg, tmp_path / "run")
    assert result.metrics["transport_converged"] == 0.0 and result.metrics["transport_max_relative_mass_error"] > 1e-3
    assert any(line.startswith("the transport's Newton stopped at its time or round limit") for line in result.verdict)
    assert all(v == 1.0 for k, v in result.metrics.items() if k.startswith("holds_"))


@pytest.mark.parametrize("override, message", [
    ("target.image=missing.png", "does not exist"),
    ("target.image=black.png", "all black"),
    ("target.width=20.0", "can light only"),
    ("constraints.max_slope=-1", "constraints.max_slope"),
    ("seconds=0", "time budget"),
    ("checkpoint_every=0", "^checkpoint_every=0 must be an integer >= 1"),
    ("previews=[0.5,-2]", r"^previews=\[0.5, -2\] must be a list of factors > 0"),
    ("+design_method.foo=1", "^unknown key design_method.foo; design_method takes name, start"),
    ("design_method.transport_iterations=0", "^design_method.transport_iterations=0 must be an integer >= 1"),
])
def test_bad_input_is_refused_in_one_line_before_any_run_opens(tmp_path, override, message):
    _png(tmp_path / "black.png", np.zeros((16, 16)))
    cfg = compose_design([*SMALL, override], tmp_path)
    with pytest.raises((ValueError, FileNotFoundError), match=message) as error:
        prepare_design(cfg, tmp_path)
    assert "\n" not in str(error.value)
    assert not (tmp_path / "mlruns").exists()


def test_the_command_line_says_it_in_one_line_and_opens_no_run(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "experiments.apps.design", *SMALL, "target.image=missing.png",
                           f"tracking.store_dir={tmp_path / 'mlruns'}", f"hydra.run.dir={tmp_path / 'run'}"],
                          cwd=tmp_path, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1, proc.stderr[-2000:]
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and "does not exist" in lines[0], proc.stderr[-2000:]
    assert not (tmp_path / "mlruns").exists() and not (tmp_path / "run" / "metrics.json").exists()
