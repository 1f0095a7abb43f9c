"""Starts of the iteration (framework/reconstruction/starts/): the inverse refraction through the operator's own
light path against a paraboloid lens's closed-form normals, the masked transport start against
known prints (height-field operator and the two lenses), the exit path of the mesh operator
against its own tracer, and bad inputs."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from framework.core.data import ReconstructionData
from framework.core.masks import mask_from_height_field
from framework.core.problem import HeightGrid, Problem
from framework.core.contracts.start import StartRequest
from framework.reconstruction.starts import TransportStart
from framework.reconstruction.starts.transport import exit_directions, fit_masked_surface
from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.optics.inverse_refraction import snell_normals
from operators.light_paths import flat_exit, refract_down
from operators.mesh.operator import MeshSceneOperator
from operators.scene import Receiver, Scene

CONF = str(Path(__file__).resolve().parents[2] / "conf")
INDEX_OF = lambda scene: float(np.mean(scene.indices))  # noqa: E731


def refract(direction: np.ndarray, normal: np.ndarray, eta: float) -> np.ndarray:
    """Vector Snell (independent of the code under test): unit normals facing the incident side."""
    cos_i = -(direction * normal).sum(axis=1, keepdims=True)
    root = np.sqrt(1.0 - eta ** 2 * (1.0 - cos_i ** 2))
    return eta * direction + (eta * cos_i - root) * normal


def paraboloid(m: int, radius: float, height: float) -> np.ndarray:
    """A plano-convex lens cap d = height (1 - r^2 / radius^2) on r < radius, 0 outside (m, m)."""
    c = np.linspace(-1, 1, m)
    x, y = np.meshgrid(c, c)
    return np.clip(height * (1.0 - (x ** 2 + y ** 2) / radius ** 2), 0.0, None)


def height_field_problem(truth: np.ndarray, photons: int = 262144, receiver: int = 64) -> Problem:
    """Noise-free data of ``truth`` (m, m) through the height-field operator, its mask and volume."""
    scene = Scene(receiver=Receiver(resolution=receiver))
    operator = CausticOperator(scene, OperatorSettings(photons=photons, footprint_px=3.0, dtype="float64"))
    grid = HeightGrid(truth.shape[0], 1.0, scene.substrate.thickness)
    d = torch.from_numpy(truth)
    data = ReconstructionData(target=operator.render(d), mask=mask_from_height_field(d, 1e-3, 0.05),
                              volume=float(d.sum()) * grid.cell_area, delta=0.05)
    return Problem(operator, data, grid, scene)


def request(problem: Problem) -> StartRequest:
    return StartRequest(problem, Path("."))


def test_the_inverse_refraction_gives_a_paraboloids_normals_in_closed_form():
    scene = Scene()
    operator = CausticOperator(scene, OperatorSettings(photons=4096))
    index, h, a = INDEX_OF(scene), scene.substrate.thickness, 0.3
    rng = np.random.default_rng(1)
    xy = rng.uniform(-0.6, 0.6, (400, 2))
    d = a * (0.5 - (xy ** 2).sum(axis=1))  # paraboloid d = a (0.5 - r^2): slopes -2 a (x, y)
    normal = np.column_stack([2 * a * xy, np.ones(len(xy))])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    top = np.column_stack([xy, h + d])
    incident = top - np.asarray(scene.light.position)
    incident /= np.linalg.norm(incident, axis=1, keepdims=True)
    inside = refract(incident, normal, 1.0 / index)  # the paraboloid's own light path, forward
    bottom = xy + inside[:, :2] * ((h + d) / -inside[:, 2])[:, None]
    out = refract(inside, np.tile([0.0, 0.0, 1.0], (len(xy), 1)), index)
    landing = bottom + out[:, :2] * (scene.receiver.z / out[:, 2])[:, None]

    found, error = exit_directions(operator, xy, h + d, landing, refract_down(incident, 1.0 / index), index, steps=30)
    assert error.max() < 1e-10
    np.testing.assert_allclose(snell_normals(incident, found, index), normal, atol=1e-9)


def test_the_masked_surface_fit_integrates_exact_slopes_and_holds_the_volume():
    # d = a (s^2 - x^2)(s^2 - y^2) on |x|, |y| < s, quadratic along every grid line: the mean of an
    # edge's end slopes is its exact difference quotient; samples at |x| = s lie on the grid (d = 0).
    m, a, s = 51, 2.0, 0.6
    c = np.linspace(-1, 1, m)
    x, y = np.meshgrid(c, c)
    box = (np.abs(x) <= s + 1e-12) & (np.abs(y) <= s + 1e-12)
    truth = np.where(box, a * (s * s - x * x) * (s * s - y * y), 0.0)
    slopes = np.stack([-2 * a * x * (s * s - y * y), -2 * a * y * (s * s - x * x)], axis=-1) * box[..., None]
    mask = (np.abs(x) < s - 1e-12) & (np.abs(y) < s - 1e-12)
    d = fit_masked_surface(slopes, mask, c[1] - c[0], smoothness=0.0, height_sum=float(truth.sum()))
    assert np.all(d[~mask] == 0.0) and d[mask].sum() == pytest.approx(truth.sum(), rel=1e-12)
    np.testing.assert_allclose(d, truth, atol=1e-12)


def test_the_transport_start_finds_a_paraboloid_lens_before_any_iteration():
    truth = paraboloid(32, 0.6, 0.08)
    problem = height_field_problem(truth)
    start = TransportStart(photons=131072)(request(problem))
    d = start.d.double().numpy()
    assert np.all(d[~problem.data.mask.numpy()] == 0.0) and d.min() >= 0.0 and d.max() <= 0.3
    assert start.metrics["transport_volume_ratio"] == pytest.approx(1.0, abs=0.02)
    assert np.linalg.norm(d - truth) / np.linalg.norm(truth) < 0.15  # flat glass: 1.0
    assert start.shaped  # the solver begins at its finest preconditioner length


def two_lenses(photons: int, receiver: int = 64, dtype: str = "float64") -> MeshSceneOperator:
    with initialize_config_dir(config_dir=CONF, version_base=None):
        cfg = OmegaConf.to_container(compose("simulate", overrides=["operator=two_lenses"]), resolve=True)
    scene = Scene(receiver=Receiver(z=cfg["receiver"]["z"], resolution=receiver))
    settings = {k: v for k, v in cfg["operator"].items() if k not in ("name", "elements")}
    return MeshSceneOperator.from_config(scene, photons, 0, elements=cfg["operator"]["elements"],
                                         **{**settings, "dtype": dtype, "footprint_px": 3.0})


def test_the_exit_path_through_the_two_lenses_lands_photons_where_the_mesh_operator_does():
    operator = two_lenses(photons=8192)
    arrivals = operator.arrivals(8192)
    index = INDEX_OF(operator.scene)
    exits = flat_exit(arrivals.points, arrivals.directions, index, operator.scene.substrate.thickness)
    landed = operator.land_from_bottom(*exits)
    fine = operator.fine  # the configured operator renders 4 x finer (operators/supersample.py): its photons
    pos, _, flux, _, _ = fine.trace(torch.zeros(16, 16, dtype=torch.float64), 0, 8192)
    half = operator.scene.receiver.half_width
    traced = ((pos.T.numpy() + 0.5) / fine._to_pixels - half)[arrivals.photon]
    # Photons that reach the receiver and leave through the bottom (not a side wall, which the
    # start's flat slab does not model: 29 of 7710 here).
    bottom = (np.abs(exits[0]) <= operator.scene.substrate.half_width).all(axis=1)
    reached = (flux.numpy()[arrivals.photon] > 0) & bottom
    assert reached.sum() > 0.5 * len(arrivals.photon) and np.isfinite(landed[reached]).all()
    assert np.abs(landed[reached] - traced[reached]).max() < 1e-6 * 2 * half


def test_a_bump_through_the_two_lenses_starts_within_30_percent_of_its_heights():
    c = np.linspace(-1, 1, 32)
    x, y = np.meshgrid(c, c)
    truth = 0.05 * np.exp(-((x - 0.1) ** 2 + (y + 0.1) ** 2) / (2 * 0.25 ** 2))
    truth[truth < 1e-3] = 0.0
    operator = two_lenses(photons=131072, dtype="float32")
    grid = HeightGrid(32, 1.0, operator.scene.substrate.thickness)
    d = torch.from_numpy(truth)
    data = ReconstructionData(target=operator.render(d).double(), mask=mask_from_height_field(d, 1e-3, 0.05),
                              volume=float(d.sum()) * grid.cell_area, delta=0.05)
    problem = Problem(operator, data, grid, operator.scene)
    start = TransportStart(photons=32768)(request(problem)).d.double().numpy()
    assert np.linalg.norm(start - truth) / np.linalg.norm(truth) < 0.3


def test_bad_inputs_get_one_line_each():
    truth = paraboloid(32, 0.4, 0.05)
    problem = height_field_problem(truth, photons=65536)
    data = problem.data
    empty = Problem(problem.operator, ReconstructionData(data.target, torch.zeros_like(data.mask), None, 0.05),
                    problem.grid, problem.scene)
    with pytest.raises(ValueError, match="data.mask has no printed cell"):
        TransportStart(photons=16384)(request(empty))
    dark = data.target.clone()
    dark[:, 8:56, 8:56] = 0.0  # no light anywhere near the lens's reach
    unlit = Problem(
        problem.operator, ReconstructionData(dark, data.mask, data.volume, 0.05), problem.grid, problem.scene
    )
    with pytest.raises(ValueError, match="no light within reach of the masked region"):
        TransportStart(photons=16384)(request(unlit))
    cells = int(data.mask.sum())
    heavy = Problem(
        problem.operator,
        ReconstructionData(data.target, data.mask, 2 * cells * 0.3 * problem.grid.cell_area, 0.05),
        problem.grid,
        problem.scene,
    )
    with pytest.raises(ValueError, match="unreachable .* check volume"):
        TransportStart(photons=16384)(request(heavy))
    for key, value in (("reach", 2.0), ("photons", 0), ("p2", -1.0)):
        with pytest.raises(ValueError, match=f"initial.{key}"):
            TransportStart(**{key: value})


def test_flat_glass_is_no_shape_and_a_design_is():
    from framework.reconstruction.starts.simple import DesignStart, ZeroStart
    problem = height_field_problem(paraboloid(16, 0.6, 0.08))
    assert not ZeroStart()(request(problem)).shaped
    design = torch.from_numpy(paraboloid(16, 0.5, 0.08))
    assert DesignStart()(request(replace(problem, data=replace(problem.data, design=design)))).shaped
