"""How far the light of a design reaches on its screen: flat glass's shadow, which the design's
screen must hold, and the lit square of a preview.

Without optical elements the paraxial shadow is exact enough and needs no render
(framework/design/design_target.py, ``paraxial_shadow``). Through lenses, prisms or
meshes (an operator with ``elements``) the light's extent is measured instead: the heights
rendered on a screen :data:`WIDE` times wider than the paraxial shadow, and the farthest pixel
with light from the axis.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
import torch

from framework.design.design_target import paraxial_shadow
from operators.image_operator import ImageOperator
from operators.scene import Scene

__all__ = ["has_elements", "lit_half_width"]

MEASURING_PHOTONS = 262144
WIDE = 4.0   # the measuring screen's half width over the paraxial shadow
LIT = 1e-4   # a pixel has light above this fraction of the brightest


def has_elements(operator: Any) -> bool:
    """Whether ``operator`` traces optical elements besides the print and the substrate."""
    return bool(operator.elements)


def lit_half_width(operator_for: Callable[[Scene], ImageOperator], scene: Scene, heights: np.ndarray,
                   seed: int) -> float:
    """Half width (scene units) of the centred square that holds every lit pixel of ``heights``
    (m, m, scene units) rendered by the configured operator (``operator_for`` a scene;
    :data:`MEASURING_PHOTONS` photons, ``seed``) on a screen at ``scene``'s receiver plane
    :data:`WIDE` times the paraxial shadow wide."""
    n = scene.receiver.resolution
    wide = replace(scene, receiver=replace(scene.receiver, half_width=WIDE * paraxial_shadow(scene)))
    operator = operator_for(wide).variant(MEASURING_PHOTONS, seed, n)
    image = operator.render(torch.from_numpy(heights).to(operator.dtype)).detach().double().sum(dim=0).numpy()
    if not image.max() > 0.0:
        raise ValueError(f"no light reaches the screen at receiver.z={scene.receiver.z:g}; check light and receiver.z")
    rows, columns = np.nonzero(image > LIT * image.max())
    pixel = 2.0 * wide.receiver.half_width / n
    centres = (np.arange(n) + 0.5) * pixel - wide.receiver.half_width
    farthest = max(np.abs(centres[rows]).max(), np.abs(centres[columns]).max())
    return float(min(farthest + pixel, wide.receiver.half_width))
