"""The pixel noise a noise level stands for: the standard deviation of white noise whose norm is
the data's ``delta`` ||b||_W over the pixels a fit uses (the defect report's evidence, the tracks'
confidence, a parametric fit's misfit in noise units)."""

from __future__ import annotations

import math

import torch

from operators.values import checked_number

__all__ = ["pixel_noise", "pixels_used"]


def pixels_used(target: torch.Tensor, weights: torch.Tensor | None) -> int:
    """The number of pixels the fit uses (weight > 0; all of ``target``'s without weights)."""
    return target.numel() if weights is None else int((weights > 0).sum())


def pixel_noise(target: torch.Tensor, delta: float, weights: torch.Tensor | None) -> float:
    """The standard deviation s of white pixel noise whose norm is ``delta`` ||b||_W over the pixels
    the fit uses (weight > 0): s = delta ||b||_W / sqrt(count)."""
    checked_number(delta, "delta", above=0.0, unit="the relative noise level", example="0.05")
    squares = target.double() ** 2
    if weights is None:
        return delta * math.sqrt(float(squares.sum()) / squares.numel())
    count = pixels_used(target, weights)
    if count == 0:
        raise ValueError("every pixel has weight 0; the photo leaves nothing to fit")
    return delta * math.sqrt(float((squares * weights.double()).sum()) / count)
