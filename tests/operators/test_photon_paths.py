"""Photon differentials, orientation of the caustic and dispersion."""

from __future__ import annotations

import torch

from operators.heightfield.trace_reference import trace_substrate
from tests.operators.conftest import bump, make_operator


def test_footprint_vectors_match_neighbouring_traced_rays():
    op = make_operator(photons=10_000)
    heights = bump(32, (0.2, 0.1), 0.25, 0.08)
    emitter = op.emitter
    g = torch.Generator().manual_seed(0)
    targets = torch.cat([torch.rand(2, 200, generator=g, dtype=torch.float64) * 1.2 - 0.6,
                         torch.full((1, 200), 0.1, dtype=torch.float64)])
    channel = torch.zeros(200, dtype=torch.int64)
    hits = trace_substrate(heights, op.scene, emitter.photons_toward(targets, channel), op.glass_index)
    eps = 1e-6
    for axis in range(2):
        shifted = targets.clone()
        shifted[axis] += eps
        moved = trace_substrate(heights, op.scene, emitter.photons_toward(shifted, channel), op.glass_index)
        # The differential maps a unit step to a step of footprint_radius on the plane z = h.
        finite = (moved.position - hits.position) / eps * emitter.footprint_radius
        assert torch.allclose(hits.footprint[axis], finite, rtol=1e-4, atol=1e-4 * emitter.footprint_radius)
    assert float(hits.footprint.abs().max()) > 2 * emitter.footprint_radius * 0.5


def brightest_pixel(image: torch.Tensor) -> tuple[int, int]:
    index = int(torch.argmax(image[0]))
    return divmod(index, image.shape[-1])


def test_bump_at_positive_x_or_y_focuses_light_there():
    op = make_operator(photons=200_000, resolution=64)
    row, col = brightest_pixel(op.render(bump(48, (0.5, 0.0), 0.12, 0.05)))
    assert col > 32 + 8 and abs(row - 31.5) < 4
    row, col = brightest_pixel(op.render(bump(48, (0.0, 0.5), 0.12, 0.05)))
    assert row > 32 + 8 and abs(col - 31.5) < 4


def test_shorter_wavelength_is_deflected_more_by_a_glass_wedge():
    op = make_operator(photons=200_000, resolution=64, half_width=1.5, wavelengths=(0.45, 0.65))
    axis = torch.linspace(-1, 1, 32, dtype=torch.float64)
    wedge = 0.1 * (axis + 1).expand(32, 32)  # thicker toward +x: a prism with its base at +x
    x = torch.tensor(op.scene.receiver.pixel_centres(), dtype=torch.float64)

    def centroid_x(image):
        return (image.sum(dim=1) * x).sum(dim=1) / image.sum(dim=(1, 2))

    shift = centroid_x(op.render(wedge)) - centroid_x(op.render(torch.zeros(32, 32)))
    blue, red = float(shift[0]), float(shift[1])
    assert blue > red > 0.0  # toward the base, more for the higher index at 0.45 um
    n_blue, n_red = op.scene.indices
    assert 1.0 < blue / red < 1.3 * (n_blue - 1) / (n_red - 1)
