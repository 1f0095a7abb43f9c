"""The height-field photon kernels in C (operators/kernels/heightfield_photons.c) against the numba
kernels they stand in for, and through them against the torch path (tests/operators/test_fused.py)."""

from __future__ import annotations

import platform
import shutil

import numpy as np
import pytest
import torch

from operators.heightfield import trace_compiled
from operators.kernels import simd
from tests.operators.conftest import make_operator
from tests.operators.test_fused import smooth_random_heights

needs_compiled = pytest.mark.skipif(not trace_compiled.AVAILABLE, reason="compiled extension not built")
SIMD = [False, True] if simd.AVAILABLE else [False]


@pytest.mark.skipif(platform.system() != "Linux" or shutil.which("cc") is None, reason="no C compiler here")
def test_extension_with_the_photon_kernels_is_built_where_a_compiler_is():
    # With a C compiler at install the extension must be there: else every first run waits for numba.
    assert trace_compiled.AVAILABLE


def _pair(**settings):
    """The same operator with the C kernels and with the numba kernels."""
    return make_operator(kernels="c", **settings), make_operator(kernels="numba", **settings)


@needs_compiled
@pytest.mark.parametrize("use_simd", SIMD)
@pytest.mark.parametrize("fresnel, wavelengths", [(False, (0.633,)), (True, (0.45, 0.65))])
@pytest.mark.parametrize("footprint", [3.0, "cell"])
def test_compiled_render_and_gradient_equal_the_numba_kernels(use_simd, fresnel, wavelengths, footprint):
    c_op, nb_op = _pair(photons=30_000, resolution=48, wavelengths=wavelengths, fresnel=fresnel, chunk_size=11_000,
                        simd=use_simd, footprint_px=footprint, min_footprint_px=0.3)
    assert c_op.fused.compiled and not nb_op.fused.compiled
    heights = smooth_random_heights(seed=11)
    image_c, image_nb = c_op.render(heights), nb_op.render(heights)
    assert float(image_nb.sum()) > 0
    # Rounding only: fastmath numba against strict C, amplified where the footprints are tiny.
    assert float((image_c - image_nb).abs().max()) <= 1e-9 * float(image_nb.abs().max())
    weights = torch.randn(c_op.output_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(12))
    grad_c, grad_nb = c_op.vjp(heights, weights), nb_op.vjp(heights, weights)
    assert float(grad_nb.abs().max()) > 0
    assert float((grad_c - grad_nb).abs().max()) <= 1e-8 * float(grad_nb.abs().max())


@needs_compiled
def test_baseline_build_of_the_compiled_kernels_equals_the_numba_kernels(monkeypatch):
    # The build for CPUs without AVX2 (its loops vectorise two photons wide, or not at all).
    monkeypatch.setattr(trace_compiled._KERNELS, "suffix", "")
    c_op, nb_op = _pair(photons=30_000, resolution=48, wavelengths=(0.45, 0.65), fresnel=True, simd=False,
                        footprint_px="cell", min_footprint_px=0.3)
    heights = smooth_random_heights(seed=19)
    image_c, image_nb = c_op.render(heights), nb_op.render(heights)
    assert float((image_c - image_nb).abs().max()) <= 1e-9 * float(image_nb.abs().max())
    weights = torch.randn(c_op.output_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(20))
    grad_c, grad_nb = c_op.vjp(heights, weights), nb_op.vjp(heights, weights)
    assert float((grad_c - grad_nb).abs().max()) <= 1e-8 * float(grad_nb.abs().max())


@needs_compiled
@pytest.mark.parametrize("use_simd", SIMD)
def test_compiled_float32_images_equal_the_numba_kernels(use_simd):
    c_op, nb_op = _pair(photons=30_000, resolution=40, dtype="float32", simd=use_simd, footprint_px="cell",
                        min_footprint_px=0.3)
    heights = smooth_random_heights(seed=13).float()
    image_c, image_nb = c_op.render(heights), nb_op.render(heights)
    assert image_c.dtype == torch.float32
    assert float((image_c - image_nb).abs().max()) <= 1e-5 * float(image_nb.abs().max())


@needs_compiled
def test_compiled_kernels_record_and_replay_the_hits_as_the_numba_kernels_do():
    c_op, nb_op = _pair(photons=20_000, resolution=32)
    heights = smooth_random_heights(seed=14).numpy()
    for op in (c_op, nb_op):
        op.recorded = np.empty(op.photons)
        out = op.fused.image_buffers(np.dtype("float64"))
        op.reached = op.fused.render(heights, 0, op.photons, out, hit_t=op.recorded)
        op.image = out.sum(axis=0)
        replayed = op.fused.image_buffers(np.dtype("float64"))
        assert op.fused.render(heights, 0, op.photons, replayed, hit_t=op.recorded, replay=True) == pytest.approx(
            op.reached, rel=1e-13)
        assert np.abs(replayed.sum(axis=0) - op.image).max() <= 1e-12 * op.image.max()
    assert np.abs(c_op.recorded - nb_op.recorded).max() <= 1e-12 * np.abs(nb_op.recorded).max()
    assert c_op.reached == pytest.approx(nb_op.reached, rel=1e-12)


@needs_compiled
def test_compiled_kernels_split_the_photons_over_any_number_of_threads():
    op = make_operator(photons=50_000, resolution=32, kernels="c")
    heights = smooth_random_heights(seed=15).numpy()
    images = []
    for threads in (1, 3, 8):
        out = np.zeros((threads, *op.output_shape))
        op.fused.render(heights, 0, op.photons, out)
        images.append(out.sum(axis=0))
    for image in images[1:]:
        assert np.abs(image - images[0]).max() <= 1e-12 * images[0].max()


@needs_compiled
def test_compiled_kernels_repeat_a_render_and_a_gradient_to_the_last_bit():
    # Each thread sums a fixed share of the photon blocks into its own image: the same config
    # gives the same image, gradient and run in every run, whichever thread is scheduled first.
    op = make_operator(photons=200_000, resolution=64, chunk_size=1 << 17, kernels="c")
    heights = smooth_random_heights(seed=16)
    target = op.render(heights * 0.5)
    for threads in (3, 8):
        renders = []
        for _ in range(3):
            out = np.zeros((threads, *op.output_shape))
            op.fused.render(heights.numpy(), 0, op.photons, out)
            renders.append(out.sum(axis=0))
        assert all(np.array_equal(renders[0], image) for image in renders[1:])
    runs = [op.loss_and_grad(heights, target)[:2] for _ in range(3)]
    assert all(loss == runs[0][0] and torch.equal(grad, runs[0][1]) for loss, grad in runs[1:])


@needs_compiled
def test_compiled_aimed_rays_equal_the_numba_tracer():
    from operators.wavefront.renderer import WavefrontRenderer, _trace_native

    renderer = WavefrontRenderer(make_operator(wavelengths=(0.45, 0.65), fresnel=True).scene, vertices=65,
                                 fresnel=True)
    d = np.ascontiguousarray(smooth_random_heights(seed=16).numpy())
    rng = np.random.default_rng(17)
    aim = rng.uniform(-1.05, 1.05, (5000, 2))  # some beyond the top square: off the block's top
    sc = renderer.fused.constants(d)
    pos_c, ratio_c, path_c = np.empty((5000, 2)), np.empty(5000), np.empty(5000)
    pos_nb, ratio_nb, path_nb = np.empty((5000, 2)), np.empty(5000), np.empty(5000)
    trace_compiled.trace_aimed(d, sc, 1.46, aim, pos_c, ratio_c, path_c)
    _trace_native(d, sc, 1.46, aim, pos_nb, ratio_nb, path_nb)
    assert len(np.unique(path_nb)) >= 3  # straight through, mirrored by a wall, and others
    np.testing.assert_array_equal(path_c, path_nb)
    np.testing.assert_array_equal(ratio_c == 0.0, ratio_nb == 0.0)
    kept = ratio_nb > 0.0
    assert np.abs(pos_c[kept] - pos_nb[kept]).max() <= 1e-9
    assert np.abs(ratio_c - ratio_nb).max() <= 1e-12


@needs_compiled
def test_compiled_rasterisers_equal_the_numba_rasterisers():
    from operators.wavefront import coverage

    rng = np.random.default_rng(18)
    k, n = 40, 24
    axis = np.linspace(-2.0, n + 2.0, k)
    vertices = np.stack(np.meshgrid(axis, axis), axis=-1) + rng.normal(0.0, 0.4, (k, k, 2))  # folds and flips
    flux = rng.uniform(0.0, 1.0, (2, k - 1, k - 1)) * (rng.uniform(size=(2, k - 1, k - 1)) > 0.1)
    triangles = rng.uniform(-3.0, n + 3.0, (3000, 3, 2))
    triangles[::7] = triangles[::7, :1] + rng.normal(0.0, 0.2, (429, 3, 2))  # small ones, some inside one pixel
    weights = rng.uniform(0.0, 1.0, 3000)
    grid_c, list_c = coverage.rasterize_grid(vertices, flux, n), coverage.rasterize_triangles(triangles, weights, n)
    grid_nb = np.zeros((3, n, n))
    list_nb = np.zeros((3, n, n))
    coverage._rasterize_grid(np.ascontiguousarray(vertices), flux, grid_nb)
    coverage._rasterize_list(triangles, weights, list_nb)
    assert grid_c.sum() > 0 and list_c.sum() > 0
    assert np.abs(grid_c - grid_nb.sum(axis=0)).max() <= 1e-12 * grid_c.max()
    assert np.abs(list_c - list_nb.sum(axis=0)).max() <= 1e-12 * list_c.max()


@needs_compiled
def test_compiled_kernels_refuse_buffers_they_would_overrun():
    op = make_operator(photons=5_000, resolution=16, kernels="c")
    d = smooth_random_heights().numpy()
    with pytest.raises(ValueError, match="threads >= 1"):
        op.fused.render(d, 0, op.photons, np.zeros((0, *op.output_shape)))
    with pytest.raises(ValueError, match="hit_t"):
        op.fused.render(d, 0, op.photons, op.fused.image_buffers(np.dtype("float64")), hit_t=np.empty(10))
    with pytest.raises(ValueError, match="float64"):
        op.fused.vjp(d, 0, op.photons, op.fused.pad_gradient(np.zeros(op.output_shape)),
                     np.zeros((1, *d.shape), dtype=np.float32))
