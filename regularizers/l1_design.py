"""A prior toward the print's design: R(d) = alpha ||d - c||_1 within the bounds (c: the design).

A print differs from its design in a few places (an interruption, a droplet, a line too low): the
deviation d - c is sparse, which an L1 penalty on it favours, as eq. (7)'s L1 favours sparse
heights (docs/method.md, "Defects against the design").
"""

from __future__ import annotations

import math

import torch

from operators.values import checked_height_field, checked_number

from ._checks import checked_bounds
from .base import Regularizer
from .shrinkage import clamp_on_mask, soft_shrink


class PixelL1DesignBounds(Regularizer):
    """R(d) = alpha ||d - c||_1 + iota_C(d), C = {p1 <= d_j <= p2 on N^, d_j = 0 on N°}, c the design
    of the :class:`RegularizerContext`. Plugin ``l1_design``.

    prox_{step R}(w)_j = I_[p1,p2](c_j + S(w_j - c_j, step alpha)) on the mask, 0 off it: exact for
    the reason of eq. (7) (regularizers/l1_bounds.py): each sample's function is convex in one
    variable, so its minimiser over an interval is the clamp of the free minimiser.

    Args:
        alpha: Weight >= 0 of the L1 deviation (same unit as l1_bounds' alpha).
        p1: Lower height bound on the mask, scene units.
        p2: Upper height bound on the mask, scene units.
    """

    length_keys = ("p1", "p2")

    has_prox = True
    smooth = False

    def __init__(self, alpha: float = 2e-3, p1: float = 0.0, p2: float = 0.3) -> None:
        self.alpha = checked_number(
            alpha, "alpha", least=0.0, unit="the weight of the deviation from the design", example="2e-3"
        )
        self.p1, self.p2 = checked_bounds(p1, p2)

    def _design_for(self, d: torch.Tensor) -> torch.Tensor:
        design = self.ctx.design
        if design is None:
            raise ValueError("regularizer l1_design needs the print's design: give height_field.path with measured "
                             "data, or data.printed with synthetic data")
        if tuple(design.shape) != tuple(d.shape):
            raise ValueError(f"design has shape {tuple(design.shape)}, the heights {tuple(d.shape)}; give the "
                             "design on the height grid")
        return design.to(device=d.device, dtype=d.dtype)

    def value(self, d: torch.Tensor) -> float:
        """alpha ||d - c||_1 if d is in C (within 1e-12), else ``inf``."""
        checked_height_field(d)
        if float((d - self.project(d)).abs().max()) > 1e-12:
            return math.inf
        return self.alpha * float((d - self._design_for(d)).abs().sum())

    def project(self, d: torch.Tensor) -> torch.Tensor:
        """Projection onto C: clamp to [p1, p2] on the mask, 0 off it; shape (m, m)."""
        checked_height_field(d)
        return clamp_on_mask(d, self._mask_for(d), self.p1, self.p2)

    def prox(self, d: torch.Tensor, step: float) -> torch.Tensor:
        """I_[p1,p2](c + S(d - c, step alpha)) on the mask, 0 off it; shape (m, m)."""
        checked_height_field(d)
        c = self._design_for(d)
        return clamp_on_mask(c + soft_shrink(d - c, self._check_step(step) * self.alpha), self._mask_for(d),
                             self.p1, self.p2)
