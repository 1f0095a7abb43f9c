"""Designs through optical elements (the two lenses of conf/operator/two_lenses.yaml), the printable
start and the Hellinger data term: the measured shadow against the paraxial one, a caustic of a
known print through the lenses designed back, a transport start that breaks the limits projected
onto them, the Hellinger term's gradient."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from framework.design.design_target import paraxial_shadow
from framework.core.image_metrics import relative_l2
from framework.design.design_run import _start, run_design
from framework.design.design_setup import prepare_design
from framework.design.design_screen import WIDE, lit_half_width
from framework.design.design_refinement import _hellinger, _l2_ssim
from tests.design.conftest import SMALL, compose_design

LENSES = ["operator=two_lenses", "receiver.z=-1.0"]  # the paper's screen, 5 mm below the lower lens


def test_the_measured_shadow_of_flat_glass_is_the_paraxial_one(tmp_path):
    cfg = compose_design([*SMALL, "target.resolution=128", "height_field.resolution=64"], tmp_path)
    setup = prepare_design(cfg)
    scene = replace(setup.scene, receiver=replace(setup.scene.receiver, resolution=128))
    measured = lit_half_width(setup.operator_for, scene, np.zeros((64, 64)), 0)
    wide_pixel = 2.0 * WIDE * paraxial_shadow(scene) / 128
    # The farthest lit pixel's centre plus one pixel: within a pixel and a half of the paraxial rim
    # (the rim's rays meet the glass at 0.1 rad, where the paraxial scale is good to 1e-3).
    assert abs(measured - paraxial_shadow(scene)) < 1.5 * wide_pixel, (measured, paraxial_shadow(scene))


@pytest.mark.slow
def test_a_caustic_through_two_lenses_is_designed_back(tmp_path):
    # The target: the caustic of a smooth bump through the lenses, by the operator's exact references
    # (its own tracer, 4x finer receiver, cell footprints, other photons): not the design's model.
    cfg = compose_design([*SMALL, *LENSES, "seconds=10", "previews=[]", "constraints.min_feature=null"], tmp_path)
    setup = prepare_design(cfg)
    x = np.linspace(-1.0, 1.0, 32)
    xx, yy = np.meshgrid(x, x)
    bump = 0.12 * np.exp(-((xx - 0.25) ** 2 + yy ** 2) / (2 * 0.3 ** 2))
    assert all(setup.constraints.holds(bump).values())
    exact = setup.operator.exact_variant(1 << 20, 77, setup.scene.receiver.resolution)
    caustic = exact.render(torch.from_numpy(bump)).detach().double().numpy()[0]
    np.save(tmp_path / "bump_caustic.npy", caustic)
    # 20 s: the start (about 8 s on an idle machine) may take half of them, L-BFGS the rest.
    cfg = compose_design([*SMALL, *LENSES, "seconds=20", "previews=[0.5,2.0]", "constraints.min_feature=null",
                          f"target.image={tmp_path / 'bump_caustic.npy'}"], tmp_path)
    setup = prepare_design(cfg)
    assert any("optical elements" in note for note in setup.notes)
    result = run_design(cfg, tmp_path / "run", setup=setup)
    assert all(v == 1.0 for k, v in result.metrics.items() if k.startswith("holds_"))
    # The screen at half the distance (z = -0.5) would cut the meniscus (down to z = -0.8): skipped, said.
    assert (tmp_path / "run" / "preview_2x.npy").is_file() and not (tmp_path / "run" / "preview_0.5x.npy").exists()
    assert any(line.startswith("no preview at 0.5x") for line in result.verdict)
    # Flat glass misses the bump's caustic by its whole structure; the design finds most of it.
    assert setup.flat_discrepancy > 0.3, setup.flat_discrepancy
    assert result.metrics["relative_l2"] < 0.5 * setup.flat_discrepancy, (result.metrics, setup.flat_discrepancy)


@pytest.mark.slow
def test_the_transport_design_alone_taller_than_the_room_below_the_upper_lens_still_ends_printable(tmp_path):
    # Blind to the lenses, the transport design of logo through them fits heights that reach into the
    # upper lens (z = 1.0, 0.9 above the glass); its iterations are scored as printed (clipped to the
    # height limit) and the printed design is the projection of the fit.
    small = [o for o in SMALL if not o.startswith("design_method.")]  # the transport's screen is the target's
    cfg = compose_design([*small, *LENSES, "target.width=40 mm", "target.image=logo", "design_method=schwartzburg",
                          "seconds=30", "previews=[]"], tmp_path)
    setup = prepare_design(cfg)
    result = run_design(cfg, tmp_path / "run", setup=setup)
    assert math.isnan(result.metrics["unprojected_relative_l2"])  # the fit itself reaches into the lens
    assert all(v == 1.0 for k, v in result.metrics.items() if k.startswith("holds_"))
    assert result.metrics["printed_max_height"] <= setup.constraints.max_height * (1 + 1e-9)
    assert math.isfinite(result.metrics["relative_l2"])  # the printed design renders (as badly as flat glass:
    # the transport design alone does not see the lenses, docs/results.md)


def test_a_transport_start_beyond_the_limits_is_projected_onto_them(tmp_path):
    cfg = compose_design([*SMALL, "target.image=text", "constraints.max_slope=0.3"], tmp_path)
    setup = prepare_design(cfg)
    d0, metrics = _start(setup)
    assert metrics["transport_printable"] == 0.0
    assert all(setup.constraints.holds(d0.double().numpy(), rtol=1e-6).values())  # to the operator's float32
    flat = setup.operator.render(torch.zeros_like(d0)).double().numpy()
    start = setup.operator.render(d0).double().numpy()
    target = setup.target.numpy()
    assert relative_l2(start, target) < relative_l2(flat, target)  # still a start toward the target


@pytest.mark.parametrize("term", ["hellinger", "l2_ssim"])
def test_the_other_data_terms_have_their_finite_difference_gradients(term, tmp_path):
    cfg = compose_design([*SMALL, "target.image=ring", "operator.dtype=float64"], tmp_path)
    problem = prepare_design(cfg).problem
    x = np.linspace(-1.0, 1.0, 32)
    xx, yy = np.meshgrid(x, x)
    d = torch.from_numpy(0.05 * np.exp(-(xx ** 2 + yy ** 2) / 0.3))
    direction = torch.from_numpy(np.cos(3 * xx) * np.exp(-(xx ** 2 + yy ** 2) / 0.5))

    def data_term(h):
        return _hellinger(problem, h) if term == "hellinger" else _l2_ssim(problem, h, 0.05)

    _, grad, _ = data_term(d)
    step = 1e-5
    difference = (data_term(d + step * direction)[0] - data_term(d - step * direction)[0]) / (2 * step)
    assert difference == pytest.approx(float((grad * direction).sum()), rel=1e-4)
    if term == "l2_ssim":  # the L2 part is the problem's own data term
        assert _l2_ssim(problem, d, 1e-300)[0] == pytest.approx(problem.fidelity.evaluate(d, with_grad=False).value,
                                                                rel=1e-12)
