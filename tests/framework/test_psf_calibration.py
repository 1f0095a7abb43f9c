"""The screen blur's width as a calibration parameter: the pixel-integrated Gaussian kernel
(operators/imaging.py), its analytic derivative in sigma, and psf_sigma fitted jointly with the gain
(framework/lab/calibration.py)."""

from __future__ import annotations

import json
import math

import pytest
import torch
import torch.nn.functional as F

from framework.lab.calibration import JointCalibration
from framework.reconstruction.reconstruction import run_reconstruction
from framework.reconstruction.parts import Reconstruction
from operators.heightfield.operator import CausticOperator
from operators.linear.gaussian_blur import GaussianBlur
from operators.imaging import ImagingOperator
from operators.stack import StackOperator
from tests.experiments.conftest import SMALL, compose_reconstruct
from tests.operators.conftest import bump, make_operator

N = 64
PIXEL = 2.0 / N  # receiver pixel of make_operator's [-1, 1] receiver at N pixels
TRUE_GAIN = 1.3


def _normal_cdf(x: float) -> float:
    return 0.5 * (1.0 + math.erf(x / math.sqrt(2.0)))


@pytest.mark.parametrize("sigma_px", [0.3, 0.5, 1.0, 2.5])
def test_taps_are_the_gaussian_integrated_over_each_pixel(sigma_px: float) -> None:
    blur = GaussianBlur(sigma_px * PIXEL, PIXEL)
    radius = (blur.profile.numel() - 1) // 2
    assert radius >= 6 * sigma_px  # the taps reach 6 sigma
    raw = [_normal_cdf((k + 0.5) / sigma_px) - _normal_cdf((k - 0.5) / sigma_px) for k in range(-radius, radius + 1)]
    expected = torch.tensor(raw, dtype=torch.float64) / sum(raw)
    assert torch.allclose(blur.profile, expected, rtol=0.0, atol=1e-14)
    assert float(blur.profile.sum()) == pytest.approx(1.0, abs=1e-14)
    if sigma_px == 0.5:  # below a pixel the neighbours keep their weight: Phi(-1) - Phi(-3) each
        assert float(blur.profile[radius + 1]) == pytest.approx(0.157305, abs=2e-6)


@pytest.mark.parametrize("sigma_px", [1.0, 1.5, 3.0])
def test_the_kernel_s_variance_is_sigma_squared_plus_the_pixel_box(sigma_px: float) -> None:
    blur = GaussianBlur(sigma_px * PIXEL, PIXEL)
    k = torch.arange(blur.profile.numel(), dtype=torch.float64) - (blur.profile.numel() - 1) // 2
    variance = float((blur.profile * k ** 2).sum())
    assert variance == pytest.approx(sigma_px ** 2 + 1.0 / 12.0, rel=1e-6)  # a box of one pixel convolved


@pytest.mark.parametrize("sigma_px", [0.2, 0.5, 1.5])
def test_the_blur_and_its_derivative_are_self_adjoint(sigma_px: float) -> None:
    blur = GaussianBlur(sigma_px * PIXEL, PIXEL)
    g = torch.Generator().manual_seed(1)
    x, y = (torch.rand(2, N, N, generator=g, dtype=torch.float64) for _ in range(2))
    for forward in (blur.apply, blur.derivative):
        lhs, rhs = float((forward(x) * y).sum()), float((x * forward(y)).sum())
        assert abs(lhs - rhs) < 1e-12 * abs(lhs)
    assert torch.equal(blur.adjoint(x), blur.apply(x))


def test_a_width_far_below_a_pixel_is_no_blur_and_its_derivative_vanishes() -> None:
    assert not GaussianBlur(0.0, PIXEL).active and not GaussianBlur(0.02 * PIXEL, PIXEL).active
    assert GaussianBlur(0.1 * PIXEL, PIXEL).active  # 2.9e-7 of the light on each neighbour
    image = torch.rand(1, N, N, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    sizes = [float(GaussianBlur(s * PIXEL, PIXEL).derivative(image).norm()) for s in (0.4, 0.2, 0.1, 0.05)]
    assert sizes[0] > sizes[1] > sizes[2] > sizes[3] >= 0.0 and sizes[2] < 1e-3 * sizes[0]


def _imaging(sigma_px: float, gain: float = TRUE_GAIN, photons: int = 1 << 15) -> ImagingOperator:
    model = make_operator(photons=photons, resolution=N, seed=0)
    return ImagingOperator(lambda scene: CausticOperator(scene, model.settings), model.scene, sigma_px * PIXEL, gain)


@pytest.mark.parametrize("sigma_px", [0.3, 0.5, 1.5])
def test_the_sigma_column_matches_central_differences_of_the_render(sigma_px: float) -> None:
    op = _imaging(sigma_px)
    d = bump(N, sigma=0.25, height=0.06)
    calibration = JointCalibration(op, ["gain", "psf_sigma"])
    image, jac = calibration.jacobian(d, ["psf_sigma"])
    sigma, h = sigma_px * PIXEL, 1e-4 * sigma_px * PIXEL
    plus = op.render_with(op.scene, op.gain, d, sigma + h).double()
    minus = op.render_with(op.scene, op.gain, d, sigma - h).double()
    numeric = (plus - minus) / (2.0 * h)
    assert float((jac[0] - numeric).norm()) < 1e-4 * float(jac[0].norm())
    assert torch.allclose(image, op.render(d).double(), rtol=1e-14, atol=0.0)


def _photo(sigma_px: float, truth: torch.Tensor) -> torch.Tensor:
    """gain * K(sigma) F_ref(truth) + 1% noise: F_ref a finer render with other photons, area-averaged."""
    reference = make_operator(photons=1 << 17, resolution=N, seed=0).variant(1 << 19, 11, 2 * N).render(truth)
    caustic = F.avg_pool2d(reference.unsqueeze(0), 2).squeeze(0)
    clean = TRUE_GAIN * GaussianBlur(sigma_px * PIXEL, PIXEL).apply(caustic)
    noise = torch.randn(clean.shape, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    return clean + 0.01 * float(clean.norm()) / float(noise.norm()) * noise


@pytest.mark.parametrize("sigma_px", [0.5, 1.5])
def test_width_and_gain_are_recovered_at_the_true_heights(sigma_px: float, tmp_path) -> None:
    truth = bump(N, sigma=0.25, height=0.06)
    photo = _photo(sigma_px, truth)
    op = _imaging(1.0, gain=0.7 * TRUE_GAIN, photons=1 << 17)  # starts at one pixel, the gain 30% off
    calibration = JointCalibration(op, ["gain", "psf_sigma"])
    calibration.setup(photo, None, 0.01, tmp_path / "calibration.json")
    for _ in range(4):
        values = calibration.update(truth)
    assert values["psf_sigma"] == pytest.approx(sigma_px * PIXEL, rel=0.1)
    assert values["gain"] == pytest.approx(TRUE_GAIN, rel=0.02)
    assert op.psf_sigma == values["psf_sigma"] and op.blur.sigma == values["psf_sigma"]
    report = calibration.report()
    assert report["calibration_psf_sigma_initial"] == pytest.approx(PIXEL)
    assert report["calibration_psf_sigma_px"] == pytest.approx(values["psf_sigma"] / PIXEL)
    assert report["calibration_psf_sigma_mm"] == pytest.approx(values["psf_sigma"] * op.scene.mm_per_unit)
    assert 0 < report["calibration_psf_sigma_std_px"] < 0.05 * sigma_px
    assert report["calibration_psf_sigma_std_mm"] == pytest.approx(report["calibration_psf_sigma_std"] * 25.0)
    saved = json.loads((tmp_path / "calibration.json").read_text())
    assert saved["values"]["psf_sigma"] == pytest.approx(values["psf_sigma"])
    assert saved["psf_sigma_px"] == pytest.approx(report["calibration_psf_sigma_px"])
    assert saved["std"]["psf_sigma"] == pytest.approx(report["calibration_psf_sigma_std"])


def test_a_stack_shares_one_width_and_its_column_is_the_sum_of_the_shots(tmp_path) -> None:
    model = make_operator(photons=1 << 14, resolution=32, seed=0)
    shots = [ImagingOperator(lambda scene: CausticOperator(scene, model.settings), model.scene, 0.05, g)
             for g in (1.0, 2.0)]
    calibration = JointCalibration(StackOperator(shots), ["gain", "psf_sigma"], scene=model.scene)
    d = bump(32)
    _, jac = calibration.jacobian(d, ["psf_sigma"])
    h = 1e-5
    numeric = (calibration.setup_of.render(d, {"psf_sigma": 0.05 + h})
               - calibration.setup_of.render(d, {"psf_sigma": 0.05 - h})) / (2 * h)
    assert float((jac[0] - numeric).norm()) < 1e-4 * float(jac[0].norm())
    calibration.setup_of.apply({"psf_sigma": 0.03})
    assert [shot.psf_sigma for shot in shots] == [0.03, 0.03] and calibration.values()["psf_sigma"] == 0.03


def test_the_start_is_the_override_else_screen_sigma_else_one_pixel(tmp_path) -> None:
    op = _imaging(0.0, photons=1 << 12)
    settings = {"params": ["gain", "psf_sigma"]}
    scene = op.scene
    assert JointCalibration.from_config(op, settings, scene).initial["psf_sigma"] == pytest.approx(PIXEL)
    assert JointCalibration.from_config(op, settings, scene, 0.02).initial["psf_sigma"] == 0.02
    given = JointCalibration.from_config(op, {**settings, "psf_sigma_start": "0.5 mm"}, scene, 0.02)
    assert given.initial["psf_sigma"] == pytest.approx(0.02)  # 0.5 mm at 25 mm per unit
    assert op.psf_sigma == 0.0  # the configured screen until the data are set ...
    given.setup(torch.ones(op.output_shape, dtype=torch.float64), None, 0.05, tmp_path / "c.json")
    assert op.psf_sigma == pytest.approx(0.02) and op.blur.active  # ... then the start


@pytest.mark.parametrize("settings, screen_sigma, message", [
    ({"psf_sigma_start": None}, -0.01, r"^screen.sigma=-0.01 cannot start calibration.params' psf_sigma"),
    ({"psf_sigma_start": None}, math.nan, r"^screen.sigma=nan cannot start"),
    ({"psf_sigma_start": "-0.1 mm"}, 0.0, r"^calibration.psf_sigma_start='-0.1 mm' must be a length > 0"),
    ({"psf_sigma_start": 0.0}, 0.0, r"^calibration.psf_sigma_start=0.0 must be a length > 0"),
    ({"psf_sigma_start": "wide"}, 0.0, r"^calibration.psf_sigma_start='wide' must be a number"),
    ({"params": ["gain"], "psf_sigma_start": 0.01}, 0.0, r"lacks psf_sigma: add it, or drop the start"),
])
def test_bad_widths_are_refused_in_one_line(settings, screen_sigma, message) -> None:
    op = _imaging(0.0, photons=1 << 12)
    with pytest.raises(ValueError, match=message) as error:
        JointCalibration.from_config(op, {"params": ["gain", "psf_sigma"], **settings}, op.scene, screen_sigma)
    assert "\n" not in str(error.value)
    with pytest.raises(ValueError, match=r"^calibration.psf_sigma_start=inf must be a length > 0"):
        JointCalibration(op, ["psf_sigma"], psf_sigma_start=math.inf)


def test_a_config_with_a_negative_screen_sigma_is_refused_before_any_render(tmp_path) -> None:
    cfg = compose_reconstruct([*SMALL, "screen.sigma=-0.01", "calibration.params=[gain,psf_sigma]"], tmp_path)
    with pytest.raises(ValueError, match=r"^screen.sigma=-0.01 cannot start calibration.params' psf_sigma"):
        Reconstruction.from_config(cfg, tmp_path)
    cfg = compose_reconstruct([*SMALL, "screen.psf=gaussian", "screen.sigma=inf"], tmp_path)
    with pytest.raises(ValueError, match=r"^screen.psf=gaussian needs a finite screen.sigma > 0"):
        Reconstruction.from_config(cfg, tmp_path)


@pytest.mark.slow
def test_a_run_reports_the_width_in_scene_units_pixels_and_mm(tmp_path) -> None:
    cfg = compose_reconstruct([*SMALL, "solver.max_iter=2", "screen.psf=gaussian", "screen.sigma=0.5mm",
                               "calibration.params=[gain,psf_sigma]", "calibration.psf_sigma_start=0.04"], tmp_path)
    metrics = run_reconstruction(cfg, tmp_path / "run", tmp_path)
    assert metrics["calibration_psf_sigma"] == pytest.approx(0.04)  # not yet updated: the fit is far from 2 delta
    assert metrics["calibration_psf_sigma_px"] == pytest.approx(0.04 / (2.0 / 64))
    assert metrics["calibration_psf_sigma_mm"] == pytest.approx(1.0)
    saved = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert saved["calibration_psf_sigma_px"] == pytest.approx(1.28)
    assert json.loads((tmp_path / "run" / "calibration.json").read_text())["psf_sigma_mm"] == pytest.approx(1.0)
