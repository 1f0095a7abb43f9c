"""The AVX2 splat and gather (operators/kernels/simd_kernels.c) against the numba kernels they stand in for."""

from __future__ import annotations

import platform
from pathlib import Path

import numba as nb
import numpy as np
import pytest
import torch

from operators.kernels import simd
from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.scene import Receiver, Scene
from operators.splat import compiled
from operators.splat.native import gather_padding, pad_for_gather, splat_backward, splat_forward
from operators.splat.splat import footprint_capacity, footprint_half_extent
from framework.scene.printed_shapes import make_shape
from tests.python_subprocess import run_json_script

needs_simd = pytest.mark.skipif(not simd.AVAILABLE, reason="AVX2 extension not built or CPU without AVX2")


def _cpu_has_avx2() -> bool:
    cpuinfo = Path("/proc/cpuinfo")
    return cpuinfo.exists() and {"avx2", "fma"} <= set(cpuinfo.read_text().split())


@pytest.mark.skipif(platform.machine() != "x86_64" or not _cpu_has_avx2(), reason="not an x86-64 CPU with AVX2")
def test_extension_is_built_and_used_where_the_cpu_has_avx2():
    # An install whose C build failed would fall back to numba silently; on this CPU that is a defect.
    assert simd.AVAILABLE


# Semi-axes (px) of the test footprints and the image side: most fit the 8 x 8 box, some do not;
# or long thin footprints at any angle, which the AVX2 kernels take row by row over the ellipse's
# chords where the box lies on the image.
SMALL, LARGE = ((1.5, 3.6), (1.5, 6.0), 64), ((0.6, 4.0), (4.0, 40.0), 256)


def _in_spans(pos: np.ndarray, metric: np.ndarray, resolution: int) -> int:
    """Photons whose bounding box exceeds the 8 x 8 box and lies on the image with 3 columns to
    spare: those the AVX2 kernels take over the chords."""
    det = metric[0] * metric[2] - metric[1] ** 2
    hx, hy = np.sqrt(metric[2] / det), np.sqrt(metric[0] / det)
    x0, x1 = np.ceil(pos[0] - hx), np.floor(pos[0] + hx)
    y0, y1 = np.ceil(pos[1] - hy), np.floor(pos[1] + hy)
    large = (x1 - x0 >= 8) | (y1 - y0 >= 8)
    return int(np.count_nonzero(large & (x0 >= 0) & (y0 >= 0) & (y1 <= resolution - 1) & (x1 + 3 <= resolution - 1)))


def _photons(count: int, resolution: int, seed: int, axes=SMALL):
    """Footprints of the semi-axis ranges of ``axes`` at random angles, some hanging over the
    image border."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-4.0, resolution + 4.0, (2, count))
    (a_lo, a_hi), (b_lo, b_hi), _ = axes
    a, b, angle = rng.uniform(a_lo, a_hi, count), rng.uniform(b_lo, b_hi, count), rng.uniform(0, np.pi, count)
    c, s = np.cos(angle), np.sin(angle)
    metric = np.stack([c * c / a**2 + s * s / b**2, c * s * (1 / a**2 - 1 / b**2), s * s / a**2 + c * c / b**2])
    flux = rng.uniform(0.1, 1.0, count)
    channel = rng.integers(0, 2, count)
    return pos, metric, flux, channel


def _splat(pos, metric, flux, channel, resolution, dtype, use_simd, c_kernels=False):
    """The image (2, n, n) summed over the threads' images: numba's splat (with or without the
    AVX2 kernels) or, with ``c_kernels``, the C splat of given photons."""
    out = np.zeros((nb.get_num_threads(), 2, resolution, resolution), dtype=dtype)
    if c_kernels:
        compiled.splat_spots(pos, metric, flux, channel, out, footprint_capacity(metric))
    else:
        splat_forward(pos, metric, flux, channel, out, footprint_capacity(metric), use_simd)
    return out.sum(axis=0, dtype=np.float64)


def _assert_same_image(image, reference, rtol):
    """Equal to rtol of the reference's largest pixel, pixel for pixel, and of its total in all."""
    assert np.abs(image - reference).max() <= rtol * np.abs(reference).max()
    assert abs(image.sum() - reference.sum()) <= rtol * reference.sum()


@needs_simd
@pytest.mark.parametrize("axes", [SMALL, LARGE], ids=["small", "large"])
@pytest.mark.parametrize("dtype, rtol", [(np.float64, 1e-13), (np.float32, 1e-6)])
def test_avx2_splat_equals_numba_splat(dtype, rtol, axes):
    side = axes[2]
    pos, metric, flux, channel = _photons(20000, side, seed=1, axes=axes)
    assert _in_spans(pos, metric, side) > (2000 if axes is SMALL else 10000)
    _assert_same_image(_splat(pos, metric, flux, channel, side, dtype, True),
                       _splat(pos, metric, flux, channel, side, dtype, False), rtol)


@needs_simd
@pytest.mark.parametrize("axes", [SMALL, LARGE], ids=["small", "large"])
def test_avx2_gather_equals_numba_gather(axes):
    side = axes[2]
    pos, metric, flux, channel = _photons(20000, side, seed=2, axes=axes)
    assert _in_spans(pos, metric, side) > (2000 if axes is SMALL else 10000)
    grad_image = np.random.default_rng(3).standard_normal((2, side, side)) + 5.0  # a large mean: cancellation
    pad = gather_padding(footprint_half_extent(metric))
    results = []
    for use_simd in (True, False):
        g_pos, g_metric, g_flux = np.empty((2, 20000)), np.empty((3, 20000)), np.empty(20000)
        splat_backward(pos, metric, flux, channel, pad_for_gather(grad_image, pad), pad, g_pos, g_metric, g_flux,
                       use_simd, nb.get_num_threads())
        results.append((g_pos, g_metric, g_flux))
    for fast, plain in zip(*results):
        assert np.abs(fast - plain).max() <= 1e-11 * np.abs(plain).max()
    assert np.count_nonzero(results[0][2]) > 15000  # photons on the image did contribute


needs_c_splat = pytest.mark.skipif(not compiled.AVAILABLE, reason="compiled extension not built")


@needs_c_splat
@pytest.mark.parametrize("axes", [SMALL, LARGE], ids=["small", "large"])
@pytest.mark.parametrize("dtype, rtol", [(np.float64, 1e-13), (np.float32, 1e-6)])
def test_c_splat_equals_numba_splat(dtype, rtol, axes):
    # The C splat of given photons (the mesh scenes' and the torch path's) against numba's, the
    # same float64 photons, each thread the same share: equal to rounding, every photon's flux kept.
    side = axes[2]
    pos, metric, flux, channel = _photons(20000, side, seed=4, axes=axes)
    _assert_same_image(_splat(pos, metric, flux, channel, side, dtype, None, c_kernels=True),
                       _splat(pos, metric, flux, channel, side, dtype, simd.AVAILABLE), rtol)
    out = np.zeros((1, 2, side, side), dtype=dtype)
    with pytest.raises(ValueError, match=r"metric \(2, 20000\)"):
        compiled.splat_spots(pos, metric[:2], flux, channel, out, footprint_capacity(metric))
    with pytest.raises(ValueError, match=r"channels 0 \.\. 2 must lie in 0 \.\. 1"):
        compiled.splat_spots(pos, metric, flux, channel * 2, out, footprint_capacity(metric))


@needs_c_splat
@pytest.mark.parametrize("axes", [SMALL, LARGE], ids=["small", "large"])
def test_c_gather_equals_numba_gather(axes):
    side = axes[2]
    pos, metric, flux, channel = _photons(20000, side, seed=5, axes=axes)
    grad_image = np.random.default_rng(6).standard_normal((2, side, side)) + 5.0
    pad = gather_padding(footprint_half_extent(metric))
    padded = pad_for_gather(grad_image, pad)
    numba_grads = np.empty((2, 20000)), np.empty((3, 20000)), np.empty(20000)
    splat_backward(pos, metric, flux, channel, padded, pad, *numba_grads, simd.AVAILABLE, nb.get_num_threads())
    c_grads = compiled.gather_spots(pos, metric, flux, channel, padded, pad, nb.get_num_threads())
    for c, plain in zip(c_grads, numba_grads):
        assert c.dtype == np.float64
        assert np.abs(c - plain).max() <= 1e-12 * np.abs(plain).max()
    assert np.count_nonzero(c_grads[2]) > 15000
    with pytest.raises(ValueError, match="pad = 200"):
        compiled.gather_spots(pos, metric, flux, channel, padded, 200, 1)


@needs_simd
def test_operator_image_and_gradient_do_not_depend_on_simd():
    scene = Scene(receiver=Receiver(resolution=128))
    heights = torch.from_numpy(make_shape("gaussian", 32))
    grad_image = torch.from_numpy(np.random.default_rng(4).standard_normal((1, 128, 128)))
    images, grads = [], []
    for use_simd in (True, False):
        op = CausticOperator(scene, OperatorSettings(photons=40000, chunk_size=16384, dtype="float64", simd=use_simd))
        images.append(op.render(heights))
        grads.append(op.vjp(heights, grad_image))
    assert torch.allclose(images[0], images[1], rtol=1e-12, atol=1e-12 * float(images[1].abs().max()))
    assert torch.allclose(grads[0], grads[1], rtol=1e-9, atol=1e-10 * float(grads[1].abs().max()))


WITHOUT_EXTENSION = """
import importlib.abc, importlib.machinery, json, sys

class HideExtension(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "operators.kernels._simd":  # a spec without a file: as on an install without a C compiler
            return importlib.machinery.ModuleSpec(name, None)
        return None

sys.meta_path.insert(0, HideExtension())
import torch
from operators.kernels import simd
from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.scene import Receiver, Scene
from framework.scene.printed_shapes import make_shape

op = CausticOperator(Scene(receiver=Receiver(resolution=64)), OperatorSettings(photons=20000, dtype="float64"))
heights = torch.from_numpy(make_shape("gaussian", 32))
image = op.render(heights)
grad = op.vjp(heights, image)
print(json.dumps({"available": simd.AVAILABLE, "image": float(image.sum()), "grad": float(grad.abs().sum())}))
"""


def test_operator_runs_on_the_numba_kernels_without_the_extension():
    result = run_json_script(WITHOUT_EXTENSION)
    assert result["available"] is False
    op = CausticOperator(Scene(receiver=Receiver(resolution=64)),
                         OperatorSettings(photons=20000, dtype="float64", simd=False))
    heights = torch.from_numpy(make_shape("gaussian", 32))
    image = op.render(heights)
    assert result["image"] == pytest.approx(float(image.sum()), rel=1e-12)
    assert result["grad"] == pytest.approx(float(op.vjp(heights, image).abs().sum()), rel=1e-12)
