"""The design's account of the light that the substrate's clear side walls send on the screen
(framework/design/design_run.py, wall_light)."""

from __future__ import annotations

import numpy as np
import torch

from framework.design.design_run import wall_light
from framework.design.design_setup import prepare_design
from operators.wavefront.renderer import WavefrontRenderer, wavefront_vertices
from tests.design.conftest import SMALL, compose_design
from tests.operators.test_side_walls import wall_band_flux


def test_flat_glass_sends_the_closed_form_wall_light_on_the_design_screen(tmp_path):
    """Flat glass 100 mm above the screen: the walls reflect the closed-form share of the light
    (tests/operators/test_side_walls.py: 1.35%), all of it onto the screen; blackened edges
    send none, and the verdict's figures are left out."""
    setup = prepare_design(compose_design([*SMALL, "target.image=ring"], tmp_path))
    flat = np.zeros(setup.grid.shape)
    photons = 1 << 20
    caustic = WavefrontRenderer(setup.scene, vertices=wavefront_vertices(photons, 1)).render(
        torch.from_numpy(flat)).numpy()
    figures = wall_light(setup, flat, photons, caustic)
    expected = wall_band_flux(setup.scene.indices[0]) / (float(caustic.sum()) * setup.scene.receiver.pixel_size ** 2)
    assert abs(figures["wall_light_share"] / expected - 1.0) < 0.02, (figures, expected)
    assert 0.0 < figures["blackened_edges_relative_l2"] < 1.0
    blackened = prepare_design(compose_design([*SMALL, "target.image=ring", "substrate.walls=absorbing"], tmp_path))
    assert wall_light(blackened, flat, photons, caustic) == {}
