"""A regulariser plugin in one file: ``regularizer/l2_pixel``, the Tikhonov term
R(d) = alpha / 2 * ||d||_2^2 with its closed-form proximal map.

    [project.entry-points."shape_from_caustics.regularizer"]
    l2_pixel = "examples.plugins.l2_regularizer:PixelL2"

Chosen with ``+solver.regularizers.l2_pixel={alpha: 1e-3}`` (docs/plugins.md, "A newcomer's path").
"""

from __future__ import annotations

import torch

from operators.values import checked_number
from regularizers.base import Regularizer


class PixelL2(Regularizer):
    """R(d) = alpha / 2 * sum_j d_j^2 over the height samples; prox_{t R}(d) = d / (1 + t alpha).

    Args:
        alpha: Weight >= 0 (scene units^-2 of height).
    """

    has_prox = True
    smooth = True

    def __init__(self, alpha: float = 1e-3) -> None:
        self.alpha = checked_number(alpha, "alpha", least=0.0, example="1e-3")  # one line naming key and fix

    @staticmethod
    def example_settings() -> dict[str, float]:
        """The settings the contract suite builds it with."""
        return {"alpha": 0.5}

    def value(self, d: torch.Tensor) -> float:
        """alpha / 2 * ||d||^2 of heights d (m, m)."""
        return 0.5 * self.alpha * float((d.double() ** 2).sum())

    def prox(self, d: torch.Tensor, step: float) -> torch.Tensor:
        """argmin_x step * R(x) + 1/2 ||x - d||^2 = d / (1 + step * alpha), shape (m, m)."""
        return d / (1.0 + self._check_step(step) * self.alpha)
