"""The fused native path (render, vjp) against the independent torch path, photon for photon."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.operators.conftest import bump, make_operator
from tests.operators.test_gradients import directional_check

CASES = [(False, (0.633,)), (True, (0.633,)), (False, (0.45, 0.65)), (True, (0.45, 0.65))]


def smooth_random_heights(m: int = 16, seed: int = 0) -> torch.Tensor:
    """A bump plus a few random low-frequency waves, positive everywhere (m, m) float64."""
    rng = np.random.default_rng(seed)
    axis = np.linspace(-1.0, 1.0, m)
    y, x = np.meshgrid(axis, axis, indexing="ij")
    waves = sum(a * np.sin(kx * x + ky * y + p) for a, kx, ky, p in
                zip(rng.uniform(0.003, 0.008, 4), rng.uniform(-4, 4, 4), rng.uniform(-4, 4, 4), rng.uniform(0, 6, 4)))
    return bump(m, (0.1, -0.15), 0.35, 0.05) + torch.from_numpy(waves) + 0.04


@pytest.mark.parametrize("fresnel, wavelengths", CASES)
def test_fused_image_equals_torch_path_in_float64(fresnel, wavelengths):
    op = make_operator(photons=20_000, resolution=32, wavelengths=wavelengths, fresnel=fresnel, chunk_size=7_000)
    heights = smooth_random_heights()
    fused, reference = op.render(heights), op.render_reference(heights)
    assert fused.dtype == torch.float64 and fused.shape == op.output_shape
    assert float(reference.sum()) > 0
    assert torch.allclose(fused, reference, rtol=1e-10, atol=1e-10 * float(reference.abs().max()))


def test_fused_image_equals_torch_path_in_float32():
    op = make_operator(photons=20_000, resolution=32, wavelengths=(0.45, 0.65), fresnel=True, dtype="float32")
    heights = smooth_random_heights().float()
    fused, reference = op.render(heights), op.render_reference(heights)
    assert fused.dtype == torch.float32
    # The torch path traces in float32, the fused path in float64: rounding-level differences.
    assert torch.allclose(fused, reference, rtol=1e-4, atol=1e-4 * float(reference.abs().max()))
    assert abs(float(fused.sum()) - float(reference.sum())) <= 1e-5 * float(reference.sum())


@pytest.mark.parametrize("fresnel, wavelengths", CASES)
def test_fused_vjp_equals_torch_autograd(fresnel, wavelengths):
    op = make_operator(photons=20_000, resolution=32, wavelengths=wavelengths, fresnel=fresnel, chunk_size=7_000)
    heights = smooth_random_heights(seed=1)
    weights = torch.randn(op.output_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    fused, reference = op.vjp(heights, weights), op.vjp_reference(heights, weights)
    assert float(reference.abs().max()) > 0
    assert float((fused - reference).abs().max()) <= 1e-9 * float(reference.abs().max())


def test_fused_vjp_matches_finite_differences_with_fresnel_and_two_wavelengths():
    op = make_operator(photons=20_000, resolution=32, wavelengths=(0.45, 0.65), fresnel=True)
    heights = smooth_random_heights(seed=3)
    weights = torch.randn(op.output_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(4))
    for seed in range(2):
        numeric, analytic = directional_check(op, heights, weights, seed)
        assert abs(numeric - analytic) <= 2e-5 * abs(analytic), (numeric, analytic)


def test_trace_only_pass_reports_the_flux_that_the_image_holds():
    op = make_operator(photons=20_000, resolution=64, half_width=1.5)
    heights = smooth_random_heights().numpy()
    out = op.fused.image_buffers(np.dtype("float64"))
    reached = op.fused.render(heights, 0, op.photons, out, splat=False)
    assert not out.any()
    splatted = op.fused.render(heights, 0, op.photons, out)
    assert reached == pytest.approx(splatted, rel=1e-12)
    assert float(out.sum()) == pytest.approx(reached, rel=1e-3)  # up to kernel truncation at the border


def test_gradient_replaying_the_hits_of_a_render_equals_searching_them_again():
    # Three chunks; a budget of 60 KiB holds the hits of the first one only (7,680 photons).
    op = make_operator(photons=20_000, resolution=32, chunk_size=7_000, hit_cache_mb=0.06)
    searching = make_operator(photons=20_000, resolution=32, chunk_size=7_000, hit_cache_mb=0.0)
    heights, other = smooth_random_heights(seed=5), smooth_random_heights(seed=6)
    weights = torch.randn(op.output_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(7))
    expected = searching.vjp(heights, weights)
    d = heights.numpy()
    op.render(heights)
    assert op.hit_cache.hits(d, 0, 7_000) is not None and op.hit_cache.hits(d, 7_000, 14_000) is None
    assert torch.allclose(op.vjp(heights, weights), expected, rtol=0, atol=1e-12 * float(expected.abs().max()))
    # Hits of other heights are never replayed: after a render of `other`, the gradient at `heights` searches.
    op.render(other)
    assert op.hit_cache.hits(d, 0, 7_000) is None
    assert torch.allclose(op.vjp(heights, weights), expected, rtol=0, atol=1e-12 * float(expected.abs().max()))


def test_replayed_hits_are_the_ones_used():
    # Corrupting the recorded hits must change the gradient: the cache is really read.
    op = make_operator(photons=20_000, resolution=32, chunk_size=7_000)
    heights = smooth_random_heights(seed=5)
    weights = torch.randn(op.output_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(7))
    op.render(heights)
    honest = op.vjp(heights, weights)
    op.hit_cache.hits(heights.numpy(), 0, 7_000)[:] += 1e-3
    assert float((op.vjp(heights, weights) - honest).abs().max()) > 1e-3 * float(honest.abs().max())
