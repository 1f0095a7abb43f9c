"""How strongly the caustic pins each height sample down: the column norms of the data term's
Jacobian and the height uncertainty they give (docs/method.md, "Defects against the design").

With the receiver image F(d) (c, n, n), per-pixel weights w and white pixel noise of standard
deviation s, moving the single sample j by h changes the weighted image by about h ||w J_j||
(J_j: column j of dF/dd). The change equals the noise of one pixel when h = s / ||w J_j||: the
sample's *conditional* standard deviation, the smallest height change at j that the caustic tells
from noise. It is large where light passing the sample is spread out or never reaches the
screen, small where it is focused. The column norms come from Rademacher probes v (E[(J^T w v)_j^2]
= ||w J_j||^2), one adjoint pass each: no Python loop over photons or pixels.
"""

from __future__ import annotations


import torch
import torch.nn.functional as F

from operators.image_operator import ImageOperator
from operators.values import checked_whole

__all__ = ["column_norms", "height_uncertainty"]


def column_norms(operator: ImageOperator, d: torch.Tensor, weights: torch.Tensor | None, probes: int, seed: int,
                 smoothing_px: int = 1) -> torch.Tensor:
    """||w J_j|| for every height sample j, shape (m, m), image units per scene unit of height.

    Args:
        operator: The forward operator F (its ``vjp``).
        d: Heights (m, m) at which J is taken (scene units).
        weights: Per-pixel weights w (c, n, n) in [0, 1], or None (1 everywhere).
        probes: Rademacher probes (adjoint passes); the estimate's relative spread is about sqrt(2 / probes)
            before smoothing.
        seed: Seed of the probes.
        smoothing_px: The squared norms are averaged over a (2 r + 1)^2 window of samples (r = this):
            neighbouring columns differ little, their average has a smaller spread. 0: none.
    """
    probes = checked_whole(probes, "probes", 1, example="16")
    shape = tuple(operator.output_shape)
    generator = torch.Generator().manual_seed(int(seed))
    squares = torch.zeros_like(d, dtype=torch.float64)
    for _ in range(probes):
        v = (torch.randint(0, 2, shape, generator=generator, dtype=torch.int64) * 2 - 1).to(d.dtype)
        if weights is not None:
            v = v * weights.to(v)
        squares += operator.vjp(d, v).double() ** 2
    squares /= probes
    if smoothing_px > 0:
        size = 2 * smoothing_px + 1
        squares = F.avg_pool2d(squares[None, None], size, stride=1, padding=smoothing_px,
                               count_include_pad=False)[0, 0]
    return squares.sqrt()


def height_uncertainty(norms: torch.Tensor, noise: float, cap: float) -> torch.Tensor:
    """The conditional standard deviation s / ||w J_j|| of every sample, shape (m, m), scene units,
    at most ``cap`` (where the caustic does not see a sample at all)."""
    floor = noise / cap
    return noise / norms.clamp(min=floor)
