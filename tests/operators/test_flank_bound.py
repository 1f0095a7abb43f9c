"""Light that may meet the printed top a second time (operators/heightfield/flank_bound.py): none
on prints with slopes up to 1, the printed fibres' range; some on steeper ones."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from operators.heightfield.flank_bound import remeet_bound
from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.scene import Receiver, Scene


def fibres(m: int, max_slope: float, angle_deg: float) -> torch.Tensor:
    """Six parallel fibres with Gaussian cross-sections (heights 0.024-0.048 units, 0.6-1.2 mm),
    each as wide as gives it the steepest flank ``max_slope``, running at ``angle_deg`` to x."""
    axis = np.linspace(-1.0, 1.0, m)
    y, x = np.meshgrid(axis, axis, indexing="ij")
    a = math.radians(angle_deg)
    across = -math.sin(a) * x + math.cos(a) * y
    d = np.zeros((m, m))
    for k, height in enumerate(np.linspace(0.024, 0.048, 6)):
        sigma = height * math.exp(-0.5) / max_slope  # the flank's steepest slope is h / sigma e^-1/2
        d += height * np.exp(-0.5 * ((across - (-0.75 + 0.3 * k)) / sigma) ** 2)
    return torch.from_numpy(d)


@pytest.mark.parametrize("angle", [0.0, 45.0])
def test_no_light_meets_the_top_again_on_prints_with_slopes_up_to_one(angle):
    op = CausticOperator(Scene(receiver=Receiver(resolution=64)), OperatorSettings(photons=400_000))
    heights = fibres(256, 1.0, angle)
    steps = [float(np.abs(np.diff(heights.numpy(), axis=a)).max()) for a in (0, 1)]
    grid_slope = max(steps) * 255 / 2.0
    assert grid_slope > 0.6  # the flanks are resolved on the grid
    assert remeet_bound(op, heights) == 0.0


def test_light_may_meet_the_top_again_on_steeper_prints():
    """Slopes of 4: the bound flags a share of the light entering the flanks (a bound, not a
    measurement of the light that does meet the top again)."""
    op = CausticOperator(Scene(receiver=Receiver(resolution=64)), OperatorSettings(photons=400_000))
    assert remeet_bound(op, fibres(256, 4.0, 0.0)) > 1e-3
