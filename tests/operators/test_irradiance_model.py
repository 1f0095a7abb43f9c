"""The default irradiance model (cell footprints, 4 x supersampled pixels; docs/method.md, "The
irradiance model") against independent truths: the exact caustic of wavefront triangles for the
true prints, a fold caustic's peak, the analytic irradiance of a flat slab, the block mean's
adjoint, energy and bit-identical reruns."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from framework.scene.scene_config import build_operator, build_scene
from framework.scene.printed_shapes import make_shape
from operators.supersample import SupersampledOperator
from operators.wavefront.renderer import WavefrontRenderer
from tests.operators.test_wavefront import _pixel_means, _slab_irradiance

CONF = Path(__file__).resolve().parents[2] / "conf"
FINAL_BUDGET = 1 << 20  # the default run's photons at most (conf/reconstruct.yaml)


def configured_model(*overrides: str) -> object:
    """The reconstruction's operator as conf/reconstruct.yaml builds it, with ``overrides``."""
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = OmegaConf.to_container(compose("reconstruct", overrides=[f"photons={FINAL_BUDGET}", *overrides]),
                                     resolve=True)
    return build_operator(cfg, build_scene(cfg))


def relative(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(torch.linalg.vector_norm(a.double() - b.double()) / torch.linalg.vector_norm(b.double()))


@pytest.fixture(scope="module")
def exact_print_lines() -> tuple[torch.Tensor, torch.Tensor]:
    heights = torch.from_numpy(make_shape("print_lines", 128))
    model = configured_model()
    return heights, WavefrontRenderer(model.scene, vertices=2049).render(heights)


@pytest.mark.parametrize("shape", ["print_lines", "letter_a"])
def test_the_true_print_renders_within_one_and_a_half_percent_of_its_exact_caustic(shape, exact_print_lines):
    """The default model at the final photon budget against wavefront triangles (2049 aim points
    per side, 0.05% from converged), relative L2 over the receiver. Measured on print_lines: 1.1%
    (the paper's 5-pixel splat: 14%)."""
    model = configured_model(f"scene={shape}")
    assert isinstance(model, SupersampledOperator) and model.fine.settings.footprint_px == "cell"
    if shape == "print_lines":
        heights, exact = exact_print_lines
    else:
        heights = torch.from_numpy(make_shape(shape, 128))
        exact = WavefrontRenderer(model.scene, vertices=2049).render(heights)
    assert relative(model.render(heights.float()), exact) < 0.015
    paper = configured_model(f"scene={shape}", "+protocol=paper")
    assert relative(paper.render(heights.float()), exact) > 0.10


def test_a_fold_caustics_peak_matches_the_exact_caustic(exact_print_lines):
    """The brightest pixel of print_lines' caustic, where two of its fold lines meet: the default
    model within 3% of the exact value (measured 1.5% low), the paper's splat a sixth below it
    (measured 16%)."""
    heights, exact = exact_print_lines
    truth = float(exact.max())
    assert abs(float(configured_model().render(heights.float()).max()) / truth - 1.0) < 0.03
    assert float(configured_model("+protocol=paper").render(heights.float()).max()) / truth < 0.9


def test_flat_glass_matches_the_analytic_irradiance():
    """The bare substrate's caustic against the pixel means of the point light's irradiance through
    a flat slab (tests/operators/test_wavefront.py) at the final budget: unbiased (the mean ratio
    within 0.1% of 1; measured 1 - 7e-7) and within 1.5% in relative L2 (the render noise of cell
    footprints: measured 1.1%)."""
    model = configured_model()
    image = model.render(torch.zeros(128, 128))
    expected = _pixel_means(lambda x, y: _slab_irradiance(x, y, model.scene.indices[0]), model.scene)
    inner = slice(8, 120)  # the lit square's edge (side walls) stays out
    rendered, truth = image[0, inner, inner].double(), torch.from_numpy(expected)[inner, inner]
    assert abs(float((rendered / truth).mean()) - 1.0) < 1e-3
    assert relative(rendered, truth) < 0.015


def test_supersampling_keeps_the_power_and_reruns_are_bit_identical():
    model = configured_model()
    heights = torch.from_numpy(make_shape("bump", 128)).float()
    first = model.render(heights)
    assert torch.equal(first, configured_model().render(heights))
    fine = model.fine.render(heights)
    assert float(first.double().sum()) * model.pixel_area == pytest.approx(
        float(fine.double().sum()) * model.fine.pixel_area, rel=1e-6)
