"""Pixel-domain L1 sparsity R(d) = alpha * ||d||_1 (M2; docs/method.md, "Regularisers")."""

from __future__ import annotations

import torch

from operators.values import checked_height_field, checked_number

from .base import Regularizer
from .shrinkage import soft_shrink


class PixelL1(Regularizer):
    """R(d) = alpha * sum_j |d_j| over all samples of the height field.

    prox_{step R}(w) = S(w, step * alpha) (soft shrinkage, elementwise). Needs no context;
    :meth:`setup` is optional.

    Args:
        alpha: Weight alpha >= 0 (paper's alpha_p; official default 2e-3, 5e-4 with wavelets).
    """

    has_prox = True
    smooth = False

    def __init__(self, alpha: float = 2e-3) -> None:
        self.alpha = checked_number(alpha, "alpha", least=0.0, unit="the L1 weight alpha_p", example="2e-3 (the paper)")

    def value(self, d: torch.Tensor) -> float:
        """alpha * ||d||_1 for d of shape (m, m)."""
        checked_height_field(d)
        return self.alpha * float(d.abs().sum())

    def prox(self, d: torch.Tensor, step: float) -> torch.Tensor:
        """S(d, step * alpha), shape (m, m)."""
        checked_height_field(d)
        return soft_shrink(d, self._check_step(step) * self.alpha)
