"""The screen's blur and the camera's gain around an operator (operators/imaging.py)."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from operators.heightfield.operator import CausticOperator
from operators.imaging import ImagingOperator, ScreenBlur
from tests.operators.conftest import bump, make_operator


def test_blur_is_self_adjoint_and_keeps_interior_energy() -> None:
    blur = ScreenBlur(sigma=0.05, pixel_size=2.0 / 64)  # 1.6 pixels
    g = torch.Generator().manual_seed(0)
    x, y = (torch.rand(2, 64, 64, generator=g, dtype=torch.float64) for _ in range(2))
    lhs = float((blur.apply(x) * y).sum())
    rhs = float((x * blur.adjoint(y)).sum())
    assert abs(lhs - rhs) < 1e-12 * abs(lhs)
    point = torch.zeros(1, 64, 64, dtype=torch.float64)
    point[0, 32, 32] = 1.0
    spot = blur.apply(point)[0]
    assert abs(float(spot.sum()) - 1.0) < 1e-12  # a spot inside the receiver keeps its light
    rows = torch.arange(64, dtype=torch.float64) - 32
    variance = float((spot.sum(dim=1) * rows ** 2).sum())
    width = math.sqrt(blur.sigma_px ** 2 + 1.0 / 12.0)  # sigma widened by the pixel box (pixel-integrated taps)
    assert abs(math.sqrt(variance) - width) < 1e-6 * width


def test_no_blur_below_a_pixel_and_bad_sigma() -> None:
    assert not ScreenBlur(0.0, 0.01).active
    with pytest.raises(ValueError, match="screen.sigma=-1"):
        ScreenBlur(-1.0, 0.01)


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
