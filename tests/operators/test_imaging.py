"""The screen's blur and the camera's gain around an operator (operators/imaging.py)."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from operators.heightfield.operator import CausticOperator
from operators.linear.gaussian_blur import GaussianBlur
from operators.imaging import ImagingOperator
from operators.linear import BlockMean
from operators.supersample import SupersampledOperator
from tests.operators.conftest import bump, make_operator


def _mean(image: torch.Tensor, factor: int) -> torch.Tensor:
    return BlockMean(factor).apply(image)


def test_blur_keeps_interior_energy_and_its_width() -> None:
    blur = GaussianBlur(sigma=0.05, pixel_size=2.0 / 64)  # 1.6 pixels
    point = torch.zeros(1, 64, 64, dtype=torch.float64)
    point[0, 32, 32] = 1.0
    spot = blur.apply(point)[0]
    assert abs(float(spot.sum()) - 1.0) < 1e-12  # a spot inside the receiver keeps its light
    rows = torch.arange(64, dtype=torch.float64) - 32
    variance = float((spot.sum(dim=1) * rows ** 2).sum())
    width = math.sqrt(blur.sigma_px ** 2 + 1.0 / 12.0)  # sigma widened by the pixel box (pixel-integrated taps)
    assert abs(math.sqrt(variance) - width) < 1e-6 * width


def test_no_blur_below_a_pixel_and_bad_sigma() -> None:
    assert not GaussianBlur(0.0, 0.01).active
    with pytest.raises(ValueError, match="screen.sigma=-1"):
        GaussianBlur(-1.0, 0.01)


def _imaging(gain: float = 1.7, sigma: float = 0.04) -> ImagingOperator:
    inner = make_operator(photons=20_000, resolution=32)
    return ImagingOperator(lambda scene: CausticOperator(scene, inner.settings), inner.scene, sigma, gain)


def test_render_is_gain_times_blurred_caustic() -> None:
    op = _imaging()
    d = bump(32)
    expected = 1.7 * op.blur.apply(op.inner.render(d))
    assert torch.allclose(op.render(d), expected, rtol=1e-12, atol=0.0)


def test_gradient_matches_finite_differences() -> None:
    op = _imaging()
    d = bump(32)
    target = op.render(bump(32, centre=(0.1, -0.05))) * 1.1
    _, grad, _ = op.loss_and_grad(d, target)
    direction = bump(32, centre=(0.2, 0.1), sigma=0.2, height=1.0)
    eps = 1e-5
    loss = lambda x: 0.5 * float(((op.render(x) - target) ** 2).sum())  # noqa: E731
    numeric = (loss(d + eps * direction) - loss(d - eps * direction)) / (2 * eps)
    analytic = float((grad * direction).sum())
    assert abs(numeric - analytic) < 1e-3 * abs(analytic)


def test_set_setup_rebuilds_and_counts_revisions() -> None:
    op = _imaging()
    first = op.inner
    op.set_setup(op.scene, 2.0)
    assert op.inner is first and op.revision == 1 and op.gain == 2.0
    farther = dataclasses.replace(op.scene, receiver=dataclasses.replace(op.scene.receiver, z=-0.1))
    op.set_setup(farther, 2.0)
    assert op.inner is not first and op.inner.scene.receiver.z == -0.1 and op.revision == 2
    with pytest.raises(ValueError, match="gain=0"):
        op.set_setup(farther, 0.0)


def _supersampled_imaging(sigma_px: float, factor: int = 4, n: int = 32) -> ImagingOperator:
    """The camera around a supersampled operator: n output pixels, each rendered factor x factor."""
    inner = make_operator(photons=40_000, resolution=n * factor, footprint_px=3.0 * factor, min_footprint_px=factor)
    coarse = dataclasses.replace(inner.scene, receiver=dataclasses.replace(inner.scene.receiver, resolution=n))
    pixel = coarse.receiver.pixel_size
    return ImagingOperator(lambda scene: SupersampledOperator(inner, coarse, factor), coarse, sigma_px * pixel, 1.3)


def test_a_supersampled_operator_is_blurred_on_its_fine_receiver_then_averaged() -> None:
    op = _supersampled_imaging(0.5)
    d = bump(32)
    fine = op.inner.fine.render(d)
    assert op.blur.pixel_size == pytest.approx(op.scene.receiver.pixel_size / 4)
    expected = 1.3 * _mean(GaussianBlur(op.psf_sigma, op.scene.receiver.pixel_size / 4).apply(fine), 4)
    assert torch.allclose(op.render(d), expected, rtol=1e-12, atol=0.0)
    # Blurring the averaged pixels instead is a different image: the averaging's box comes first.
    coarse_blur = 1.3 * GaussianBlur(op.psf_sigma, op.scene.receiver.pixel_size).apply(_mean(fine, 4))
    assert float((coarse_blur - expected).norm() / expected.norm()) > 1e-3


def test_the_supersampled_camera_s_adjoint_and_sigma_column() -> None:
    op = _supersampled_imaging(0.7)
    d = bump(32)
    g = torch.randn(op.output_shape, generator=torch.Generator().manual_seed(5), dtype=torch.float64)
    # <G'(d) v, g> = <v, G'(d)^* g>, the directional derivative by central differences.
    v = bump(32, centre=(0.2, -0.1), sigma=0.25, height=1.0)
    eps = 1e-6
    directional = (op.render(d + eps * v) - op.render(d - eps * v)) / (2 * eps)
    lhs, rhs = float((directional * g).sum()), float((op.vjp(d, g) * v).sum())
    assert lhs == pytest.approx(rhs, rel=1e-4)
    image, column = op.render_and_sigma_derivative(d)
    h = 1e-4 * op.psf_sigma
    numeric = (op.render_with(op.scene, op.gain, d, op.psf_sigma + h)
               - op.render_with(op.scene, op.gain, d, op.psf_sigma - h)) / (2 * h)
    assert torch.allclose(image, op.render(d), rtol=1e-12, atol=0.0)
    assert float((column - numeric).norm() / numeric.norm()) < 1e-6


@pytest.mark.parametrize("sigma_px", [0.5, 1.0])
def test_a_sub_pixel_width_is_found_on_the_fine_receiver_and_not_after_averaging(sigma_px: float) -> None:
    """An independent truth: sharp lines at sub-pixel positions on a 16 x finer grid, blurred there
    and area-averaged. The width that fits best, searched on a grid of widths, is the true one within
    2% when the blur acts on a 4 x finer grid before the averaging, and not when it acts after it."""
    n, f = 32, 16
    g = torch.Generator().manual_seed(2)
    sharp = torch.full((1, n * f, n * f), 0.05, dtype=torch.float64)
    for _ in range(24):
        i, j = (int(k) for k in torch.randint(0, n * f, (2,), generator=g))
        sharp[0, i, max(0, j - 60):j + 60] += 1.0
        sharp[0, max(0, i - 40):i + 40, j] += 0.5
    pixel = 1.0 / n
    photo = _mean(GaussianBlur(sigma_px * pixel, pixel / f).apply(sharp), f)
    fine4 = _mean(sharp, f // 4)
    widths = [k / 100 * sigma_px for k in range(50, 151)]

    def best(render) -> float:
        return min(widths, key=lambda s: float((render(s) - photo).norm()))

    on_fine = best(lambda s: _mean(GaussianBlur(s * pixel, pixel / 4).apply(fine4), 4))
    after_averaging = best(lambda s: GaussianBlur(s * pixel, pixel).apply(_mean(sharp, f)))
    assert on_fine == pytest.approx(sigma_px, rel=0.02)
    if sigma_px == 0.5:
        assert abs(after_averaging / sigma_px - 1.0) > 0.1
