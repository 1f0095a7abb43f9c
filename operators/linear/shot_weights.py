"""The weights of a stack's shots (operators/stack.py) on their stacked images.

With per-shot misfit weights w_i, the stacked image [F_1; ...; F_N] (N c, n, n) is seen as
W [F_i] = [sqrt(w_1) F_1; ...; sqrt(w_N) F_N], so that the squared misfit against stacked data is
sum_i w_i ||F_i - b_i||^2. W is diagonal, hence self-adjoint.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from operators.linear.linear_map import LinearMap

__all__ = ["ShotWeights"]


class ShotWeights(LinearMap):
    """W: block i of ``channels`` channels scaled by sqrt(weights[i]), every weight > 0."""

    def __init__(self, weights: Sequence[float], channels: int) -> None:
        weights = [float(w) for w in weights]
        if not weights or not all(math.isfinite(w) and w > 0.0 for w in weights):
            raise ValueError(f"stack weights {weights} must be one positive number per shot")
        self.weights = weights
        self.scales = [math.sqrt(w) for w in weights]
        self.channels = int(channels)

    def blocks(self, stacked: torch.Tensor) -> list[torch.Tensor]:
        """The shots' parts (c, n, n) of a stacked image (N c, n, n)."""
        if stacked.shape[0] != self.channels * len(self.scales):
            raise ValueError(f"a stack of {len(self.scales)} shots of {self.channels} channels has "
                             f"{self.channels * len(self.scales)} channels, got {stacked.shape[0]}")
        return list(torch.split(stacked, self.channels, dim=0))

    def weighted(self, images: Sequence[torch.Tensor]) -> torch.Tensor:
        """W [images]: the shots' images (c, n, n) each, weighted and stacked (N c, n, n)."""
        return torch.cat([image * scale for image, scale in zip(images, self.scales)], dim=0)

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        return self.weighted(self.blocks(x))

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        return self.apply(y)

    @classmethod
    def example(cls) -> tuple[LinearMap, tuple[int, ...]]:
        return cls([1.0, 2.5, 0.3], 2), (6, 4, 4)
