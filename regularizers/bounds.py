"""Area-based physical bounds: the indicator of {p1 <= d_j <= p2 on N^, d_j = 0 on N°}.

The mask N^ comes with the data (framework/core/masks.py builds it from a height field)."""

from __future__ import annotations

import math

import torch

from operators.values import checked_height_field, checked_number

from ._checks import checked_bounds
from .base import Regularizer
from .shrinkage import clamp_on_mask


class HeightBounds(Regularizer):
    """Indicator iota_C(d) of C = {d : p1 <= d_j <= p2 for j in N^, d_j = 0 for j in N°}.

    prox_{step iota_C} = projection onto C = clamp to [p1, p2] on the mask, 0 off it
    (independent of the step). Needs :meth:`setup` with the mask.

    Args:
        p1: Lower height bound in scene units (official 0.0).
        p2: Upper height bound in scene units (official 0.3); p1 <= p2.
        atol: Tolerance of the feasibility test in :meth:`value` (scene units).
    """

    length_keys = ("p1", "p2")  # may be given with a unit, e.g. '0.4 mm' (framework/core/plugin_config.py)

    has_prox = True
    smooth = False

    def __init__(self, p1: float = 0.0, p2: float = 0.3, atol: float = 1e-12) -> None:
        self.p1, self.p2 = checked_bounds(p1, p2)
        self.atol = checked_number(atol, "atol", least=0.0, unit="a feasibility tolerance", example="1e-12")

    def value(self, d: torch.Tensor) -> float:
        """0.0 if d lies in C (within ``atol``), else ``inf``."""
        checked_height_field(d)
        mask = self._mask_for(d)
        gap = (d - clamp_on_mask(d, mask, self.p1, self.p2)).abs().max()
        return 0.0 if float(gap) <= self.atol else math.inf

    def project(self, d: torch.Tensor) -> torch.Tensor:
        """Projection of d onto C: clamp to [p1, p2] on the mask, 0 off it; shape (m, m)."""
        checked_height_field(d)
        return clamp_on_mask(d, self._mask_for(d), self.p1, self.p2)

    def prox(self, d: torch.Tensor, step: float) -> torch.Tensor:
        """Projection of d onto C, shape (m, m)."""
        checked_height_field(d)
        self._check_step(step)
        return clamp_on_mask(d, self._mask_for(d), self.p1, self.p2)
