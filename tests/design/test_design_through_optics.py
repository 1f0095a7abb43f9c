"""Designs through optical elements (the two lenses of conf/operator/two_lenses.yaml) and the
printable start: the measured shadow against the paraxial one, a caustic of a known print through
the lenses designed back, a transport start that breaks the limits projected onto them."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from framework.core.image_metrics import relative_l2
from framework.pipeline.design_run import _method, _start, prepare_design, run_design
from framework.pipeline.design_screen import WIDE, lit_half_width, paraxial_shadow
from tests.design.conftest import SMALL, compose_design

LENSES = ["operator=two_lenses", "receiver.z=-4.0"]  # the screen 80 mm below the lower lens


def test_the_measured_shadow_of_flat_glass_is_the_paraxial_one(tmp_path):
    cfg = compose_design([*SMALL, "target.resolution=128", "height_field.resolution=64"], tmp_path)
    setup = prepare_design(cfg)
    scene = replace(setup.scene, receiver=replace(setup.scene.receiver, resolution=128))
    measured = lit_half_width(cfg, scene, setup.mm, np.zeros((64, 64)), 0)
    wide_pixel = 2.0 * WIDE * paraxial_shadow(scene) / 128
    # The farthest lit pixel's centre plus one pixel: within a pixel and a half of the paraxial rim
    # (the rim's rays meet the glass at 0.1 rad, where the paraxial scale is good to 1e-3).
    assert abs(measured - paraxial_shadow(scene)) < 1.5 * wide_pixel, (measured, paraxial_shadow(scene))


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
    cfg = compose_design([*SMALL, *LENSES, "seconds=10", "previews=[]", "constraints.min_feature=null",
                          f"target.image={tmp_path / 'bump_caustic.npy'}"], tmp_path)
    setup = prepare_design(cfg)
    assert any("optical elements" in note for note in setup.notes)
    result = run_design(cfg, tmp_path / "run", setup=setup)
    assert all(v == 1.0 for k, v in result.metrics.items() if k.startswith("holds_"))
    # Flat glass misses the bump's caustic by its whole structure; the design finds most of it.
    assert setup.flat_discrepancy > 0.3, setup.flat_discrepancy
    assert result.metrics["relative_l2"] < 0.5 * setup.flat_discrepancy, (result.metrics, setup.flat_discrepancy)


def test_a_transport_start_beyond_the_limits_is_projected_onto_them(tmp_path):
    cfg = compose_design([*SMALL, "target.image=text", "constraints.max_slope=0.3"], tmp_path)
    setup = prepare_design(cfg)
    d0, metrics = _start(setup, _method(cfg))
    assert metrics["transport_printable"] == 0.0
    assert all(setup.constraints.holds(d0.double().numpy(), rtol=1e-6).values())  # to the operator's float32
    flat = setup.operator.render(torch.zeros_like(d0)).double().numpy()
    start = setup.operator.render(d0).double().numpy()
    target = setup.target.numpy()
    assert relative_l2(start, target) < relative_l2(flat, target)  # still a start toward the target
