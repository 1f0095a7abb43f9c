"""The parts of a caustic design: image metrics, printing limits and their projection, the
deflection that bounds the screen's reach, target images."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from PIL import Image

from framework.design.design_target import BUILT_IN_TARGETS, load_target
from scipy.ndimage import gaussian_filter

from framework.core.image_metrics import relative_l2, ssim, ssim_tensor
from framework.design.print_constraints import PrintConstraints
from framework.core.plugin_config import build_plugin, split_name
from framework.design.design_setup import prepare_design
from framework.design.design_refinement import DesignAdam, DesignLBFGS
from framework.design.schwartzburg import SchwartzburgDesign
from operators.optics.inverse_refraction import deflection_angle
from tests.design.conftest import SMALL, compose_design


def test_the_metrics_ignore_brightness_and_see_structure():
    rng = np.random.default_rng(0)
    target = rng.uniform(0.0, 1.0, (32, 32))
    assert relative_l2(3.0 * target, target) == pytest.approx(0.0, abs=1e-12)
    assert ssim(3.0 * target, target) == pytest.approx(1.0, abs=1e-12)
    noisy = target + rng.normal(0.0, 0.1, target.shape)
    # The relative L2 of additive noise is its norm over the target's (after the scaling to equal totals).
    scaled = noisy * target.sum() / noisy.sum()
    assert relative_l2(noisy, target) == pytest.approx(np.linalg.norm(scaled - target) / np.linalg.norm(target))
    assert 0.3 < ssim(noisy, target) < 0.99
    assert ssim(np.roll(target, 5, axis=1), target) < 0.2  # uncorrelated structure


def _ssim_by_scipy(image: np.ndarray, target: np.ndarray) -> float:
    """Wang et al.'s SSIM written out with scipy's Gaussian filter (sigma 1.5, 3.5 sigma, mirrored
    edges), the image scaled to the target's total: the independent reference of ssim_tensor."""
    x = image * target.sum() / image.sum()
    values = []
    for a, b in zip(x, target):
        c1, c2 = (0.01 * b.max()) ** 2, (0.03 * b.max()) ** 2

        def blur(v):
            return gaussian_filter(v, 1.5, truncate=3.5, mode="reflect")

        mu_a, mu_b = blur(a), blur(b)
        var_a, var_b, cov = blur(a * a) - mu_a ** 2, blur(b * b) - mu_b ** 2, blur(a * b) - mu_a * mu_b
        values.append(
            np.mean((2 * mu_a * mu_b + c1) * (2 * cov + c2) / ((mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2)))
        )
    return float(np.mean(values))


@pytest.mark.parametrize("n", [3, 7, 40])  # smaller than the 11-pixel window too: mirrored more than once
def test_ssim_is_wang_et_als_and_its_gradient_is_the_finite_difference(n):
    rng = np.random.default_rng(n)
    target = rng.uniform(0.0, 1.0, (2, n, n))
    image = np.clip(target + rng.normal(0.0, 0.2, target.shape), 0.01, None)
    assert ssim(image, target) == pytest.approx(_ssim_by_scipy(image, target), abs=1e-14)
    x = torch.from_numpy(image).requires_grad_(True)
    (grad,) = torch.autograd.grad(ssim_tensor(x, torch.from_numpy(target)), x)
    direction = torch.from_numpy(rng.normal(0.0, 1.0, image.shape))
    step = 1e-6
    difference = (ssim(image + step * direction.numpy(), target) - ssim(image - step * direction.numpy(), target)) / (
        2 * step
    )
    assert difference == pytest.approx(float((grad * direction).sum()), rel=1e-6)


@pytest.mark.parametrize("image, rule", [("spot", "cell"), ("ring", "flat")])
def test_the_automatic_rim_rule_gathers_a_few_pixels_light_and_leaves_a_wide_targets_rim_where_flat_glass_sends_it(
        image, rule, tmp_path):
    if image == "spot":  # the four centre pixels: the centroids' hull holds a quarter of the samples
        picture = np.zeros((32, 32), dtype=np.uint8)
        picture[15:17, 15:17] = 255
        Image.fromarray(picture).save(tmp_path / "spot.png")
        image = str(tmp_path / "spot.png")
    problem = prepare_design(compose_design([*SMALL, f"target.image={image}"], tmp_path)).problem
    zeros = torch.zeros(problem.grid.shape, dtype=problem.operator.dtype)
    targets = {}
    for choice in ("auto", rule, "flat" if rule == "cell" else "cell"):
        design = SchwartzburgDesign(problem, zeros, smoothness=0.01, outside_hull=choice)
        design.step()
        targets[choice] = design.targets
    assert np.array_equal(targets["auto"], targets[rule])
    assert not np.array_equal(targets["cell"], targets["flat"])  # the rule decides something here
    with pytest.raises(ValueError, match=r"outside_hull='edge' must be one of flat, cell, auto"):
        SchwartzburgDesign(problem, zeros, outside_hull="edge")


def _limits(m: int = 48, **changes) -> PrintConstraints:
    values = {"max_height": 0.2, "max_slope": 0.4, "min_feature": 0.05, "volume": None, "mask": None,
              "spacing": 2.0 / (m - 1)}
    return PrintConstraints(**{**values, **changes})


def _bump(m: int = 48, height: float = 0.3, sigma: float = 0.2) -> np.ndarray:
    x = np.linspace(-1, 1, m)
    xx, yy = np.meshgrid(x, x)
    return height * np.exp(-(xx ** 2 + yy ** 2) / (2 * sigma ** 2))


def test_the_measures_are_those_of_a_known_surface():
    m = 41
    x = np.linspace(-1, 1, m)
    xx, yy = np.meshgrid(x, x)
    limits = _limits(m)
    plane = 0.3 * xx + 0.4 * yy + 0.5  # slope 0.5 everywhere, no curvature
    figures = limits.measure(plane)
    assert figures["max_slope"] == pytest.approx(0.5, rel=1e-12)
    assert figures["max_curvature"] == pytest.approx(0.0, abs=1e-9)
    bowl = xx ** 2  # second derivative 2 along x
    assert limits.measure(bowl)["max_curvature"] == pytest.approx(2.0, rel=1e-9)
    assert limits.measure(np.ones((m, m)))["volume"] == pytest.approx(limits.spacing ** 2 * m * m)


def test_a_printable_design_is_its_own_projection():
    limits = _limits()
    d = _bump(height=0.05, sigma=0.4)
    assert all(limits.holds(d).values())
    np.testing.assert_allclose(limits.project(d), d, atol=1e-6 * 0.05)


def test_the_projection_of_heights_alone_is_the_clipping():
    limits = _limits(max_slope=100.0, min_feature=None)
    d = _bump(height=0.3) - 0.05
    np.testing.assert_allclose(limits.project(d), np.clip(d, 0.0, 0.2), atol=1e-5)


@pytest.mark.parametrize("volume", [None, 0.04])
def test_every_limit_holds_exactly_after_the_projection(volume):
    rng = np.random.default_rng(1)
    limits = _limits(volume=volume)
    d = _bump(height=0.4, sigma=0.15) + 0.01 * rng.standard_normal((48, 48))
    assert not all(limits.holds(d).values())
    printable = limits.project(d)
    holds = limits.holds(printable)
    assert all(holds.values()), (holds, limits.measure(printable))
    if volume is not None:
        assert limits.measure(printable)["volume"] == pytest.approx(volume, rel=1e-9)


def test_nothing_is_printed_outside_the_mask():
    mask = np.zeros((48, 48), dtype=bool)
    mask[8:40, 8:40] = True
    printable = _limits(mask=mask).project(_bump(height=0.1, sigma=0.3))
    assert np.abs(printable[~mask]).max() == 0.0 and printable[mask].max() > 0.01


def test_the_penalty_is_zero_inside_and_grows_with_the_violation():
    limits = _limits()
    inside = torch.from_numpy(_bump(height=0.05, sigma=0.4))
    assert float(limits.penalty(inside)) == pytest.approx(0.0, abs=1e-10)
    a, b = (float(limits.penalty(torch.from_numpy(_bump(height=h)))) for h in (0.3, 0.6))
    assert 0.0 < a < b


@pytest.mark.parametrize("key, value", [("max_height", 0.0), ("max_slope", -1.0), ("min_feature", float("nan")),
                                        ("volume", 0.0)])
def test_bad_limits_name_the_key(key, value):
    with pytest.raises(ValueError, match=f"constraints.{key}"):
        _limits(**{key: value})


def test_a_volume_beyond_the_highest_print_is_refused():
    with pytest.raises(ValueError, match="constraints.volume"):
        _limits(volume=100.0).check_grid(48)


def test_the_deflection_is_that_of_snell_at_both_faces():
    index = 1.457
    assert deflection_angle(0.0, index) == 0.0
    assert deflection_angle(1e-4, index) == pytest.approx((index - 1) * 1e-4, rel=1e-6)  # thin prism
    tilt = math.atan(0.5)
    normal = np.array([-math.sin(tilt), 0.0, math.cos(tilt)])
    down = np.array([0.0, 0.0, -1.0])  # refract the vertical ray at the tilted top, then at the flat bottom
    cos_i = -down @ normal
    inside = down / index + (cos_i / index - math.sqrt(1 - (1 - cos_i ** 2) / index ** 2)) * normal
    out_x = index * inside[0]  # tangential component is kept times the index ratio at the bottom
    assert deflection_angle(tilt, index) == pytest.approx(abs(math.asin(out_x)), rel=1e-12)
    with pytest.raises(ValueError, match="max_slope"):
        deflection_angle(math.radians(89.0), index)


@pytest.mark.parametrize("name", BUILT_IN_TARGETS)
def test_built_in_targets_are_lit_square_images(name):
    target = load_target(name, 64)
    assert target.image.shape == (64, 64) and target.image.min() >= 0.0 and target.image.max() > 0.1
    assert not target.absolute and target.source == f"built-in:{name}"


def test_a_png_target_is_read_with_its_first_row_on_top(tmp_path):
    picture = np.zeros((40, 40), dtype=np.uint8)
    picture[:10, :] = 255  # the top rows of the picture are lit
    Image.fromarray(picture).save(tmp_path / "top.png")
    image = load_target(str(tmp_path / "top.png"), 40).image
    assert image[-5:].mean() > 0.9 and image[:20].max() < 0.05  # rows along +y: the top is the last rows


@pytest.mark.parametrize("make, message", [
    (lambda p: p / "missing.png", "does not exist"),
    (lambda p: (Image.fromarray(np.zeros((16, 16), np.uint8)).save(p / "black.png"), p / "black.png")[1], "all black"),
    (lambda p: (np.save(p / "nan.npy", np.full((16, 16), np.nan)), p / "nan.npy")[1], "NaN"),
    (lambda p: (np.save(p / "neg.npy", -np.ones((16, 16))), p / "neg.npy")[1], "negative"),
    (lambda p: (np.save(p / "flat.npy", np.ones((8, 16))), p / "flat.npy")[1], "square"),
    (lambda p: (p / "notes.txt").write_text("x") and p / "notes.txt", "unsupported"),
    (lambda p: "sunset", "neither a file nor a built-in"),
])
def test_bad_targets_get_one_line(tmp_path, make, message):
    with pytest.raises((ValueError, FileNotFoundError), match=message) as error:
        load_target(str(make(tmp_path)), 16)
    assert "\n" not in str(error.value)


def test_lbfgs_after_adam_steps_takes_adams_steps_then_descends(tmp_path):
    problem = prepare_design(compose_design([*SMALL, "target.image=ring"], tmp_path)).problem
    d0 = torch.zeros(problem.grid.shape, dtype=problem.operator.dtype)
    adam = DesignAdam(problem, d0, lr=1e-3, penalty_weight=300.0)
    hybrid = DesignLBFGS(problem, d0, penalty_weight=300.0, adam_steps=3, adam_lr=1e-3)
    for _ in range(3):
        adam.step()
        hybrid.step()
    assert torch.equal(hybrid.state.d, adam.state.d) and float(hybrid.state.d.abs().max()) > 1e-3
    before = hybrid.objective(hybrid.state.d)[0]
    values = [hybrid.step().objective for _ in range(3)]  # L-BFGS: Armijo's decrease at every step
    assert before > values[0] >= values[1] >= values[2]


def test_sfcs_lbfgs_turns_a_one_pixel_gradient_into_a_broad_first_step(tmp_path):
    # sfc's method (conf/design_method/sfc.yaml) starts L-BFGS from the Sobolev smoothing
    # (I - l^2 Laplace)^-2, l = 0.3 scene units, as its inverse Hessian: a gradient on one height sample
    # becomes a step spread over about l, not a spike (docs/design.md, "Why the smoothing").
    cfg = compose_design([*SMALL, "height_field.resolution=64"], tmp_path)
    setup = prepare_design(cfg)
    problem = setup.problem
    name, params = split_name(setup.settings.method.solver, "design_method.solver")
    solver = build_plugin("design", name, params, "design_method.solver")(problem, torch.zeros(64, 64))
    spike = torch.zeros(64, 64, dtype=torch.float64)
    spike[32, 32] = 1.0
    step = -solver._direction(spike)
    assert float(step.sum()) == pytest.approx(1.0, rel=1e-6)  # the smoothing keeps a constant's share
    spacing = problem.grid.cell_area ** 0.5  # scene units between samples
    y, x = torch.meshgrid(torch.arange(64.0), torch.arange(64.0), indexing="ij")
    radius = spacing * float(((((x - 32) ** 2 + (y - 32) ** 2) * step).sum() / step.sum()).sqrt())
    # The RMS radius of the Green's function of (I - l^2 Laplace)^-2 in the plane is 2 sqrt(2) l = 0.85;
    # the glass's edges at 1 from the spike fold its tail back (measured: 0.66). The step of the identity
    # would be the spike itself, radius 0.
    assert 0.5 < radius < 2.0 * math.sqrt(2.0) * 0.3, radius
    assert float(step.max()) < 0.05  # the spike's sample keeps under 5% of the step


def test_a_negative_count_of_adam_steps_or_ssim_weight_is_refused_by_name():
    with pytest.raises(ValueError, match="solver.adam_steps"):
        DesignLBFGS.from_config(adam_steps=-1)
    with pytest.raises(ValueError, match=r"solver.ssim_weight=-0.1 must be a number > 0"):
        DesignLBFGS.from_config(loss="l2_ssim", ssim_weight=-0.1)


def test_an_extended_light_is_refused_in_one_line(tmp_path):
    cfg = compose_design([*SMALL, "light.shape=disc", "light.size=50mm"], tmp_path)
    with pytest.raises(ValueError, match=r"^light.shape=disc: sfc-design designs for a point light") as error:
        prepare_design(cfg)
    assert "\n" not in str(error.value)
