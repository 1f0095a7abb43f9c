"""The mean over square blocks of pixels: a fine receiver seen through coarser pixels.

A camera pixel records the mean irradiance over its square; an operator that renders ``factor``
times finer (operators/supersample.py) is brought to the output pixels by A, the mean of every
factor x factor block, (c, f n, f n) -> (c, n, n). Its adjoint A^T spreads each value evenly over
its block, divided by f^2.
"""

from __future__ import annotations

import torch

from operators.linear.linear_map import LinearMap
from operators.values import checked_whole

__all__ = ["BlockMean"]


class BlockMean(LinearMap):
    """A: the mean of every ``factor`` x ``factor`` block of the last two axes (factor 1: identity)."""

    def __init__(self, factor: int) -> None:
        self.factor = checked_whole(factor, "operator.supersample", 1,
                                    must="must be an integer >= 1 (1: no supersampling)")

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        """(c, f n, f n) -> (c, n, n)."""
        f = self.factor
        if f == 1:
            return x
        c, rows, cols = x.shape
        return x.reshape(c, rows // f, f, cols // f, f).mean(dim=(2, 4))

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        """(c, n, n) -> (c, f n, f n): each value over its block, divided by f^2."""
        f = self.factor
        if f == 1:
            return y
        return y.repeat_interleave(f, dim=-2).repeat_interleave(f, dim=-1) / float(f * f)

    def output_shape(self, input_shape: tuple[int, ...]) -> tuple[int, ...]:
        c, rows, cols = input_shape
        if rows % self.factor or cols % self.factor:
            raise ValueError(f"a {rows} x {cols} image has no {self.factor} x {self.factor} blocks")
        return (c, rows // self.factor, cols // self.factor)

    @classmethod
    def example(cls) -> tuple[LinearMap, tuple[int, ...]]:
        return cls(3), (2, 12, 12)
