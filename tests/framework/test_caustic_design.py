"""The caustic-design baseline (framework/design/schwartzburg.py): the transport pushes the
light onto the target cells, the Snell normals send the light to the target points through our
own optics, and a designed surface renders back to its target."""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch

from framework.core.data import ReconstructionData
from framework.core.problem import HeightGrid, Problem
from framework.design.schwartzburg import SchwartzburgDesign, flat_magnification
from framework.optimization.semi_discrete_transport import semi_discrete_transport
from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.optics.inverse_refraction import glass_directions, snell_normals
from operators.optics.reference import refract
from operators.scene import Receiver, Scene

N = 64
CENTRES = (np.arange(N) + 0.5) / N * 2 - 1
X, Y = np.meshgrid(CENTRES, CENTRES)
PIXELS = np.stack([X.ravel(), Y.ravel()], axis=1)


def test_uniform_to_uniform_is_the_identity_and_to_a_smaller_square_a_scaling():
    plan = semi_discrete_transport(np.ones((N, N)), -1.0, 1.0, PIXELS, np.ones(N * N), tolerance=1e-6)
    assert np.abs(plan.centroids - plan.sites).max() < 1e-9 and plan.max_relative_mass_error < 1e-6
    # Uniform onto a uniform grid on [-0.6, 0.6]^2: the optimal map is x -> 0.6 x.
    plan = semi_discrete_transport(np.ones((N, N)), -1.0, 1.0, 0.6 * PIXELS, np.ones(N * N), tolerance=1e-6)
    assert np.abs(plan.centroids - plan.sites / 0.6).max() < 1e-6 and plan.max_relative_mass_error < 1e-6


def test_a_shifted_blob_is_moved_by_the_shift_and_every_cell_gets_its_mass():
    def blob(cx, cy):
        return 0.02 + np.exp(-((X - cx) ** 2 + (Y - cy) ** 2) / (2 * 0.15 ** 2))

    shift, start = np.array([0.25, -0.15]), np.array([-0.1, 0.05])
    plan = semi_discrete_transport(blob(*start), -1.0, 1.0, PIXELS, blob(*(start + shift)).ravel(), tolerance=1e-4)
    assert plan.converged and plan.max_relative_mass_error < 1e-4
    moved = plan.sites - plan.centroids
    core = np.linalg.norm(plan.sites - (start + shift), axis=1) < 0.15  # the blob, away from the 2% floor
    np.testing.assert_allclose(moved[core].mean(axis=0), shift, rtol=0.1)
    assert np.abs(moved[core] - shift).max() < 2.0 / N  # within a pixel


def test_a_transport_past_its_deadline_stops_at_the_voronoi_cells_and_says_so():
    blob = 0.02 + np.exp(-((X - 0.3) ** 2 + Y ** 2) / (2 * 0.15 ** 2))
    plan = semi_discrete_transport(np.ones((N, N)), -1.0, 1.0, PIXELS, blob.ravel(), tolerance=1e-4,
                                   deadline=time.perf_counter())
    assert not plan.converged and plan.newton_steps == 0 and np.all(plan.weights == 0.0)
    # Zero weights: each pixel's Voronoi cell is its own pixel, of mass 1 / N^2 of the uniform source.
    np.testing.assert_allclose(plan.cell_masses / plan.cell_masses.sum(), 1.0 / N ** 2, rtol=1e-6)
    assert plan.max_relative_mass_error > 0.5  # the blob's pixels ask for far more than 1 / N^2
    # Without a deadline the same transport converges.
    plan = semi_discrete_transport(np.ones((N, N)), -1.0, 1.0, PIXELS, blob.ravel(), tolerance=1e-4)
    assert plan.converged and plan.max_relative_mass_error < 1e-4


def test_snell_normals_send_the_light_to_the_targets_through_our_optics():
    rng = np.random.default_rng(0)
    light, index, receiver_z = np.array([0.0, 0.0, 10.0]), 1.457, -0.05
    points = np.column_stack([rng.uniform(-1, 1, (500, 2)), 0.1 + rng.uniform(0, 0.2, 500)])
    targets = points[:, :2] + rng.normal(0, 0.05, (500, 2))
    incident = (points - light) / np.linalg.norm(points - light, axis=1, keepdims=True)
    normals = snell_normals(incident, glass_directions(points, targets, index, receiver_z), index)
    assert (normals[:, 2] > 0).all()

    def forward(p, w, n, eta):  # refract with operators/optics/reference.py (differentials unused)
        t = lambda a: torch.from_numpy(np.ascontiguousarray(a.T))  # noqa: E731
        return refract(t(w), torch.zeros(2, 3, len(w), dtype=torch.float64), t(n), None, eta)[0].numpy().T

    inside = forward(points, incident, normals, 1.0 / index)
    bottom = points + inside * (-points[:, 2:] / inside[:, 2:])
    out = forward(bottom, inside, np.tile([0.0, 0.0, 1.0], (500, 1)), index)
    landed = bottom + out * ((receiver_z - bottom[:, 2:]) / out[:, 2:])
    assert np.abs(landed[:, :2] - targets).max() < 1e-9  # receiver units


def small_problem(heights: torch.Tensor) -> Problem:
    scene = Scene(receiver=Receiver(resolution=64))
    operator = CausticOperator(scene, OperatorSettings(photons=400_000, footprint_px=2.0, dtype="float64"))
    target = operator.render(heights)
    data = ReconstructionData(target=target, mask=torch.ones(32, 32, dtype=torch.bool), volume=None, delta=0.05)
    return Problem(operator, data, HeightGrid(32, 1.0, 0.1), scene)


def test_flat_glass_is_the_design_of_its_own_caustic():
    problem = small_problem(torch.zeros(32, 32, dtype=torch.float64))
    result = SchwartzburgDesign(problem, torch.zeros(32, 32, dtype=torch.float64)).run(20)
    assert result.accepted and float(result.d.max()) < 1e-3  # scene units; a print line is 0.08 high
    assert result.history[-1].rel_discrepancy < 1e-3


def test_a_designed_surface_renders_back_to_its_smooth_target():
    from framework.scene.printed_shapes import make_shape

    problem = small_problem(torch.from_numpy(make_shape("bump", 32, sigma=0.3, height=0.05)))
    flat = problem.fidelity.evaluate(torch.zeros(32, 32, dtype=torch.float64), with_grad=False).rel_discrepancy
    result = SchwartzburgDesign(problem, torch.zeros(32, 32, dtype=torch.float64)).run(20)
    assert result.stopped_by == "solver" and result.accepted  # the outer iterations settled
    last = result.history[-1]
    # Measured: 0.0020 against 0.0145 for flat glass; residual normal error 0.09 degrees.
    assert last.rel_discrepancy < 0.25 * flat, (last.rel_discrepancy, flat)
    assert last.extras["normal_error_deg"] < 0.5
    assert result.history[0].extras["transport_max_relative_mass_error"] < 1e-3
    assert float(result.d.max()) == pytest.approx(0.05, rel=0.25)  # the bump's height, known to nobody


def test_flat_magnification_is_the_paraxial_scale_of_flat_glass():
    assert flat_magnification(10.0, 0.1, 1.457, -0.05) == pytest.approx(1 + (0.1 / 1.457 + 0.05) / 9.9)


@pytest.mark.parametrize("scale, message", [(0.0, "no light"), (0.5, "carries 50.0% of the power")])
def test_a_black_or_dim_target_is_refused_in_one_line(scale, message):
    problem = small_problem(torch.zeros(32, 32, dtype=torch.float64))
    data = ReconstructionData(target=scale * problem.data.target, mask=problem.data.mask, volume=None, delta=0.05)
    design = SchwartzburgDesign(Problem(problem.operator, data, problem.grid, problem.scene),
                           torch.zeros(32, 32, dtype=torch.float64))
    with pytest.raises(ValueError, match=message):
        design.run(1)


@pytest.mark.parametrize("key, value", [("mass_tolerance", 0.0), ("black_level", 1.5), ("smoothness", -1.0),
                                        ("outer_tolerance", 2.0), ("power_tolerance", 0), ("source", "sun")])
def test_bad_settings_name_the_key(key, value):
    with pytest.raises(ValueError, match=f"solver.{key}"):
        SchwartzburgDesign.from_config(**{key: value})
