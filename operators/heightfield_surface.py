"""The printed glass surface z = h + S(x, y) as a differentiable ray-intersection operator."""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np
import torch

from operators.native import to_numpy
from operators.heightfield_kernels import hit_backward, hit_forward

# Catmull-Rom overshoots the sample range by at most 9/32 of it: along one axis the negative
# weights sum to -s (1 - s) / 2 >= -1/8 and the positive ones to at most 9/8, so in 2-D the
# products of one negative and one positive weight sum to at least -2 * 1/8 * 9/8 = -9/32
# (reached at the cell centre).
OVERSHOOT = 9.0 / 32.0


@dataclass(frozen=True)
class HeightFieldGrid:
    """Samples d[row, col] at x_col = -half_width + col * spacing (y likewise), on top of ``base``."""

    base: float
    half_width: float
    resolution: int

    @property
    def spacing(self) -> float:
        return 2.0 * self.half_width / (self.resolution - 1)

    def z_planes(self, d: np.ndarray) -> tuple[float, float, float]:
        """Planes (zlo, zstart, zhi) for samples ``d`` (m, m): zlo and zhi bracket the interpolated
        surface; zstart = base + min d, where the hit search starts its Newton iteration when the
        march finds no crossing (exact on unprinted areas, where d is at its minimum)."""
        lo, hi = float(d.min()), float(d.max())
        return (self.base + lo - OVERSHOOT * (hi - lo) - 1e-9, self.base + lo,
                self.base + hi + OVERSHOOT * (hi - lo) + 1e-9)


class _HeightFieldHit(torch.autograd.Function):
    @staticmethod
    def forward(ctx, heights: torch.Tensor, grid: HeightFieldGrid, origin: torch.Tensor,
                direction: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        d = to_numpy(heights).astype(np.float64)
        o = to_numpy(origin).astype(np.float64)
        w = to_numpy(direction)
        zlo, zstart, zhi = grid.z_planes(d)
        n = w.shape[1]
        t = np.empty(n, dtype=w.dtype)
        jet = np.empty((5, n), dtype=w.dtype)
        hit_forward(d, grid.base, o, w, -grid.half_width, grid.spacing, zlo, zstart, zhi, t, jet,
                    nb.get_num_threads())
        t_out = torch.from_numpy(t).to(direction.device)
        ctx.grid = grid
        ctx.save_for_backward(heights, origin, direction, t_out)
        return t_out, torch.from_numpy(jet).to(direction.device)

    @staticmethod
    def backward(ctx, grad_t: torch.Tensor | None, grad_jet: torch.Tensor | None):
        heights, origin, direction, t = ctx.saved_tensors
        grid: HeightFieldGrid = ctx.grid
        w = to_numpy(direction)
        gt = np.zeros(w.shape[1]) if grad_t is None else to_numpy(grad_t).astype(np.float64)
        gj = np.zeros((5, w.shape[1])) if grad_jet is None else to_numpy(grad_jet).astype(np.float64)
        per_thread = hit_backward(to_numpy(heights).astype(np.float64), to_numpy(origin).astype(np.float64),
                                  w, to_numpy(t), gt, gj, -grid.half_width, grid.spacing,
                                  nb.get_num_threads())
        grad = torch.from_numpy(per_thread.sum(axis=0)).to(dtype=heights.dtype, device=heights.device)
        return grad, None, None, None


def intersect_height_field(heights: torch.Tensor, grid: HeightFieldGrid, origin: torch.Tensor,
                           direction: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """First hit of rays origin + t w (w: (3, N), w_z < 0) with z = base + S(x, y).

    Returns t (N,) and the surface jet (5, N) = (S_x, S_y, S_xx, S_xy, S_yy) at the hit, both
    differentiable w.r.t. ``heights`` (m, m) (not w.r.t. the rays).
    """
    return _HeightFieldHit.apply(heights, grid, origin, direction)
