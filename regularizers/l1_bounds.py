"""The paper's pixel step, eq. (7): L1 shrinkage followed by the area-based bounds."""

from __future__ import annotations

import math

import torch

from operators.values import checked_height_field, checked_number

from ._checks import checked_bounds
from .base import Regularizer
from .shrinkage import clamp_on_mask, soft_shrink


class PixelL1Bounds(Regularizer):
    """R(d) = alpha * ||d||_1 + iota_C(d), C = {p1 <= d_j <= p2 on N^, d_j = 0 on N°}.

    Its proximal map is the paper's eq. (7):
        prox_{step R}(w)_j = I_[p1,p2](S(w_j, step * alpha))  for j in N^,
        prox_{step R}(w)_j = 0                                for j in N°.

    Why this is exact: R is separable, R(d) = sum_j g_j(d_j) with
    g_j(x) = alpha |x| + iota_[p1,p2](x) on the mask and iota_{0}(x) off it, so the prox acts
    per sample. For one sample, phi(x) = step alpha |x| + 1/2 (x - w)^2 is strictly convex on the
    real line, hence decreasing left of its minimiser S(w, step alpha) and increasing right of it;
    its minimiser over any interval [p1, p2] is therefore the clamp of the unconstrained one.
    This holds for every interval (p1 <= 0 <= p2 is not needed), and off the mask the interval is {0}.

    Args:
        alpha: L1 weight alpha_p >= 0 (official 2e-3; 5e-4 in the wavelet method M3).
        p1: Lower height bound in scene units (official 0.0).
        p2: Upper height bound in scene units (official 0.3).
        atol: Tolerance of the feasibility test in :meth:`value`.
    """

    length_keys = ("p1", "p2")  # may be given with a unit, e.g. '0.4 mm' (framework/core/plugin_config.py)

    has_prox = True
    smooth = False

    def __init__(self, alpha: float = 2e-3, p1: float = 0.0, p2: float = 0.3, atol: float = 1e-12) -> None:
        self.alpha = checked_number(alpha, "alpha", least=0.0, unit="the L1 weight alpha_p", example="2e-3 (the paper)")
        self.p1, self.p2 = checked_bounds(p1, p2)
        self.atol = checked_number(atol, "atol", least=0.0, unit="a feasibility tolerance", example="1e-12")

    def value(self, d: torch.Tensor) -> float:
        """alpha * ||d||_1 if d is in C (within ``atol``), else ``inf``."""
        checked_height_field(d)
        gap = (d - clamp_on_mask(d, self._mask_for(d), self.p1, self.p2)).abs().max()
        if float(gap) > self.atol:
            return math.inf
        return self.alpha * float(d.abs().sum())

    def project(self, d: torch.Tensor) -> torch.Tensor:
        """Projection of d onto C: clamp to [p1, p2] on the mask, 0 off it; shape (m, m)."""
        checked_height_field(d)
        return clamp_on_mask(d, self._mask_for(d), self.p1, self.p2)

    def prox(self, d: torch.Tensor, step: float) -> torch.Tensor:
        """Eq. (7): clamp_[p1,p2](S(d, step * alpha)) on the mask, 0 off it; shape (m, m)."""
        checked_height_field(d)
        k = self._check_step(step) * self.alpha
        return clamp_on_mask(soft_shrink(d, k), self._mask_for(d), self.p1, self.p2)
