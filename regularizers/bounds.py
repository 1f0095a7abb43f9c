"""Area-based physical bounds: the indicator of {p1 <= d_j <= p2 on N^, d_j = 0 on N°}.

Also builds the official simulated-data mask N^ from a ground-truth height field
(method.md section 4, M2: |d_true| >= 1e-3 dilated by 5% of the grid width, 6 px at m = 128).
"""

from __future__ import annotations

import math
from typing import Literal

import torch
import torch.nn.functional as F

from framework.registry import register

from ._checks import check_bounds, check_height_field, check_nonnegative
from .base import Regularizer
from .shrinkage import clamp_on_mask


@register("regularizer", "bounds")
class HeightBounds(Regularizer):
    """Indicator iota_C(d) of C = {d : p1 <= d_j <= p2 for j in N^, d_j = 0 for j in N°}.

    prox_{step iota_C} = projection onto C = clamp to [p1, p2] on the mask, 0 off it
    (independent of the step). Needs :meth:`setup` with the mask.

    Args:
        p1: Lower height bound in scene units (official 0.0).
        p2: Upper height bound in scene units (official 0.3); p1 <= p2.
        atol: Tolerance of the feasibility test in :meth:`value` (scene units).
    """

    has_prox = True
    smooth = False

    def __init__(self, p1: float = 0.0, p2: float = 0.3, atol: float = 1e-12) -> None:
        self.p1, self.p2 = check_bounds(p1, p2)
        self.atol = check_nonnegative(atol, "atol", "pass a small feasibility tolerance such as 1e-12")

    def value(self, d: torch.Tensor) -> float:
        """0.0 if d lies in C (within ``atol``), else ``inf``."""
        check_height_field(d)
        mask = self._mask_for(d)
        gap = (d - clamp_on_mask(d, mask, self.p1, self.p2)).abs().max()
        return 0.0 if float(gap) <= self.atol else math.inf

    def prox(self, d: torch.Tensor, step: float) -> torch.Tensor:
        """Projection of d onto C, shape (m, m)."""
        check_height_field(d)
        self._check_step(step)
        return clamp_on_mask(d, self._mask_for(d), self.p1, self.p2)


def mask_from_height_field(
    d_true: torch.Tensor,
    threshold: float = 1e-3,
    dilation_fraction: float = 0.05,
    footprint: Literal["square", "disk"] = "square",
) -> torch.Tensor:
    """Printed-area mask N^ from a ground-truth height field (official simulated-data rule).

    N^ = dilate({j : |d_true_j| >= threshold}, r) with r = round(dilation_fraction * m) pixels,
    m = d_true.shape[-1] (r = 6 at m = 128). ``footprint="square"`` dilates with a
    (2r+1) x (2r+1) square (Chebyshev distance <= r), ``"disk"`` with the pixels at
    Euclidean distance <= r. Borders are not wrapped.

    Args:
        d_true: Ground-truth height field (m, m), scene units.
        threshold: Height (scene units) above which a sample counts as printed.
        dilation_fraction: Dilation radius as a fraction of the grid width, >= 0.
        footprint: Structuring element, "square" or "disk".

    Returns:
        Bool tensor (m, m) on the device of ``d_true``.

    Example:
        >>> d = torch.zeros(128, 128); d[64, 64] = 0.1
        >>> int(mask_from_height_field(d).sum())  # a 13 x 13 square
        169
    """
    check_height_field(d_true, "d_true")
    check_nonnegative(threshold, "threshold", "pass the printed-height threshold, e.g. 1e-3")
    check_nonnegative(dilation_fraction, "dilation_fraction", "pass a fraction of the grid width, e.g. 0.05")
    if footprint not in ("square", "disk"):
        raise ValueError(f"footprint={footprint!r} is not supported; pass 'square' or 'disk'")
    seed = (d_true.abs() >= threshold).to(d_true.dtype)[None, None]
    r = int(round(dilation_fraction * d_true.shape[-1]))
    if r == 0:
        return seed[0, 0] > 0
    if footprint == "square":
        grown = F.max_pool2d(seed, kernel_size=2 * r + 1, stride=1, padding=r)
    else:
        offsets = torch.arange(-r, r + 1, dtype=d_true.dtype, device=d_true.device)
        disk = (offsets[:, None] ** 2 + offsets[None, :] ** 2 <= r * r).to(d_true.dtype)
        grown = F.conv2d(seed, disk[None, None], padding=r)
    return grown[0, 0] > 0.5
