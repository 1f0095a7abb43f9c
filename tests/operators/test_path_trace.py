"""The independent path tracer of a closed glass mesh (operators/mesh/path_trace.py) against
closed forms: the power of light through a slab and a ramp (the solid angle of the glass's top
as the light sees it), energy conservation, the flat slab's wall light, and the photon model's
caustic of a flat slab within the tracer's noise."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from framework.files.mm_outputs import glass_mesh
from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.mesh.path_trace import trace_mesh
from tests.operators.test_side_walls import H, LIGHT_Z, W, slab_scene, wall_band_flux

RAYS = 1 << 20


def _solid_angle(region, half: float, samples: int = 2001) -> float:
    """The solid angle seen from (0, 0, LIGHT_Z) of the aim points on z = H in ``region(x, y)``
    within [-half, half]^2 (a midpoint rule)."""
    edges = np.linspace(-half, half, samples)
    mid = 0.5 * (edges[1:] + edges[:-1])
    x, y = np.meshgrid(mid, mid)
    dz = LIGHT_Z - H
    r = np.sqrt(x * x + y * y + dz * dz)
    return float(np.sum(np.where(region(x, y), dz / r ** 3, 0.0))) * (edges[1] - edges[0]) ** 2


@pytest.fixture(scope="module")
def flat_slab(tmp_path_factory):
    path = tmp_path_factory.mktemp("glass") / "slab.stl"
    glass_mesh(np.zeros((32, 32)), W, H, 1.0).export(path)
    scene = slab_scene("clear", 64, half_width=1.05)
    return path, scene, trace_mesh(path, scene.light.position, scene.indices[0], W, H, scene.receiver.z, 1.05, 64,
                                   RAYS, seed=0, batches=2)


def test_a_flat_slab_passes_the_light_its_top_subtends_all_of_it_to_the_receiver(flat_slab) -> None:
    _, scene, traced = flat_slab
    square = 4 * math.atan(1.0 / ((LIGHT_Z - H) * math.sqrt(2 + (LIGHT_Z - H) ** 2))) / (4 * math.pi)
    assert traced.entered == pytest.approx(square, rel=2e-3)  # uniform aim points: Monte Carlo within 0.1%
    # Every ray that entered lands (all but a millionth: rays that meet a face's edge exactly).
    assert traced.image.sum() == pytest.approx(traced.entered, rel=1e-5) and traced.dropped == 0.0


def test_a_flat_slabs_walls_reflect_their_closed_form_flux(flat_slab) -> None:
    _, scene, traced = flat_slab
    expected = wall_band_flux(scene.indices[0])
    noise = math.sqrt(expected * traced.entered / (2 * RAYS))  # the binomial share of the rays, in W
    assert abs(traced.wall_flux - expected) < 4 * noise, (traced.wall_flux, expected)


def test_the_photon_model_renders_a_flat_slab_as_the_tracer_within_its_noise(flat_slab) -> None:
    _, scene, traced = flat_slab
    model = CausticOperator(scene, OperatorSettings(photons=1 << 21, dtype="float64"))
    image = model.render(torch.zeros(32, 32, dtype=torch.float64))[0].numpy() * scene.receiver.pixel_size ** 2
    noise = 1.0 / math.sqrt(2 * RAYS / 64 ** 2)  # relative, per pixel: the rays a pixel receives
    assert np.linalg.norm(image - traced.image) / np.linalg.norm(image) < 1.3 * noise


def test_the_light_through_a_ramp_is_what_its_whole_top_subtends(tmp_path) -> None:
    """A ramp rising to 0.2 at the +x edge: aimed over a square that covers the glass, the traced
    power is the top's solid angle (the square on z = H grown by the projection of its raised
    edges); aimed at the square [-W, W]^2 on z = H it misses the rim that lies beyond that square's
    rays, and passes that square's solid angle."""
    m, rise = 64, 0.2
    x = np.linspace(-W, W, m)
    heights = np.tile(0.5 * rise * (x + W), (m, 1))
    path = tmp_path / "ramp.stl"
    glass_mesh(heights, W, H, 1.0).export(path)
    scene = slab_scene("clear", 32, half_width=1.5)
    dz = LIGHT_Z - H

    def seen(ax, ay):  # an aim point on z = H whose ray meets the ramp's top within the square
        t = dz / (dz - 0.5 * rise * (np.clip(ax, -W, None) + W))  # first guess of the scale at that height
        for _ in range(30):  # x_top = x_aim / t solves t = dz / (dz - d(x_top))
            t = dz / (dz - 0.5 * rise * (np.clip(ax / t, -W, W) + W))
        return (np.abs(ax / t) <= W) & (np.abs(ay / t) <= W)

    wide = 1.1
    traced = trace_mesh(path, scene.light.position, scene.indices[0], wide, H, scene.receiver.z, 1.5, 32, RAYS,
                        seed=1, batches=2)
    top = _solid_angle(seen, wide) / (4 * math.pi)
    assert traced.entered == pytest.approx(top, rel=3e-3)
    # All of it lands, the rim's light too: it meets the +x wall, is totally reflected and leaves
    # through the bottom (a ray restarted on the face it has just left would be lost here).
    assert traced.image.sum() == pytest.approx(traced.entered, rel=1e-5) and traced.dropped == 0.0
    square = trace_mesh(path, scene.light.position, scene.indices[0], W, H, scene.receiver.z, 1.5, 32, RAYS,
                        seed=1, batches=2)
    flat = 4 * math.atan(1.0 / (dz * math.sqrt(2 + dz ** 2))) / (4 * math.pi)
    assert square.entered == pytest.approx(flat, rel=2e-3)
    # The rim: 2% more light, the +x edge's strip (W rise / (L - h - rise) wide in aim points) and
    # the wedges along the y edges (d(x) / (L - h) wide), about (2 rise / (dz - rise) + 2 rise / dz) / 4.
    assert top / flat - 1.0 == pytest.approx((2 * rise / (dz - rise) + 2 * rise / dz) / 4, rel=0.02)
