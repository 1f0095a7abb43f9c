"""Elementwise building blocks of the pixel proximal maps: soft shrinkage and masked clamping.

Both are the method's S(w, k) and I_[p1,p2] (eq. (7); docs/method.md, "Regularisers").
"""

from __future__ import annotations

import torch


def soft_shrink(w: torch.Tensor, k: float | torch.Tensor) -> torch.Tensor:
    """Soft shrinkage S(w, k) = sign(w) * max(|w| - k, 0), elementwise.

    It is the proximal map of k * |.| (k >= 0).

    Args:
        w: Any tensor.
        k: Threshold >= 0 (scalar, or a tensor broadcastable to ``w``).

    Returns:
        Tensor of the shape, dtype and device of ``w``.

    Example:
        >>> soft_shrink(torch.tensor([-3.0, -0.5, 0.0, 0.5, 3.0]), 1.0).tolist()
        [-2.0, -0.0, 0.0, 0.0, 2.0]
    """
    return torch.sign(w) * torch.clamp(w.abs() - k, min=0.0)


def clamp_on_mask(x: torch.Tensor, mask: torch.Tensor, p1: float, p2: float) -> torch.Tensor:
    """Projection onto {x_j in [p1, p2] for j in mask, x_j = 0 otherwise}.

    Args:
        x: Height field (m, m).
        mask: Bool tensor (m, m) on the device of ``x``; True on the printed area N^.
        p1: Lower height bound (scene units), p1 <= p2.
        p2: Upper height bound (scene units).

    Returns:
        I_[p1,p2](x) on the mask, 0 off it; shape, dtype and device of ``x``.
    """
    return torch.where(mask, torch.clamp(x, p1, p2), torch.zeros((), dtype=x.dtype, device=x.device))
