"""The printed-area mask N^ of the data: where material may have been deposited.

For simulated data the rule of the paper's official code: |d_true| >= 1e-3,
dilated by 5% of the grid width (6 px at m = 128); for measured data the same rule applied to the
print's design, or a mask image (framework/files/image_io.py).
"""

from __future__ import annotations

from typing import Literal

import torch
import torch.nn.functional as F

from operators.values import checked_number, described

__all__ = ["mask_from_height_field"]


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
    if not isinstance(d_true, torch.Tensor) or d_true.ndim != 2 or not d_true.is_floating_point():
        raise ValueError(f"d_true must be a floating-point (m, m) tensor, got {described(d_true)}")
    checked_number(threshold, "threshold", least=0.0, example="1e-3")
    checked_number(dilation_fraction, "dilation_fraction", least=0.0, example="0.05")
    if dilation_fraction > 1.0:
        raise ValueError(f"dilation_fraction={dilation_fraction!r} must be at most 1 (a fraction of the grid's width)")
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
