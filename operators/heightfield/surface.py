"""The printed glass surface z = h + S(x, y) as a differentiable ray-intersection operator."""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np
import torch

from operators.heightfield.intersect_native import hit_backward, hit_forward
from operators.kernels.numba_settings import to_numpy

# Catmull-Rom overshoots the sample range by at most 9/32 of it: along one axis the negative
# weights sum to -s (1 - s) / 2 >= -1/8 and the positive ones to at most 9/8, so in 2-D the
# products of one negative and one positive weight sum to at least -2 * 1/8 * 9/8 = -9/32
# (reached at the cell centre).
OVERSHOOT = 9.0 / 32.0

# |S_x| <= SLOPE_GAIN max |d[r, c+1] - d[r, c]| / spacing (S_y likewise): along x the Catmull-Rom
# derivative of a row is c0 D0 + c1 D1 + c2 D2 in its three sample differences, with
# |c0| + |c1| + |c2| <= 3/2 (at s = 1/2: 1/8 + 5/4 + 1/8); across rows the weights' absolute
# values sum to 1 + s (1 - s) <= 5/4. A hair of margin covers rounding.
SLOPE_GAIN = 1.25 * 1.5 * (1.0 + 1e-9)


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

    def slope_bounds(self, d: np.ndarray) -> tuple[float, float]:
        """Bounds on |S_x| and |S_y| over the whole surface for samples ``d`` (m, m) (SLOPE_GAIN):
        along a ray with slope_x |w_x| + slope_y |w_y| < |w_z| the gap falls monotonically, so the
        hit search needs no march to find the first root."""
        step_x = float(np.abs(np.diff(d, axis=1)).max())
        step_y = float(np.abs(np.diff(d, axis=0)).max())
        return SLOPE_GAIN * step_x / self.spacing, SLOPE_GAIN * step_y / self.spacing


def _ray_origins(origin: torch.Tensor, n: int) -> np.ndarray:
    """Origins (3, n), float64, C-contiguous, from one origin (3,) shared by all rays or one per ray."""
    # A writable copy: a read-only view would make numba compile the kernels a second time.
    return np.require(np.broadcast_to(to_numpy(origin).astype(np.float64).reshape(3, -1), (3, n)), None, ("C", "W"))


class _HeightFieldHit(torch.autograd.Function):
    @staticmethod
    def forward(ctx, heights: torch.Tensor, grid: HeightFieldGrid, origin: torch.Tensor,
                direction: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        d = to_numpy(heights).astype(np.float64)
        w = to_numpy(direction)
        o = _ray_origins(origin, w.shape[1])
        zlo, zstart, zhi = grid.z_planes(d)
        slope_x, slope_y = grid.slope_bounds(d)
        n = w.shape[1]
        t = np.empty(n, dtype=w.dtype)
        jet = np.empty((5, n), dtype=w.dtype)
        hit_forward(d, grid.base, o, w, -grid.half_width, grid.spacing, zlo, zstart, zhi, slope_x, slope_y, t, jet,
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
        per_thread = hit_backward(to_numpy(heights).astype(np.float64), _ray_origins(origin, w.shape[1]),
                                  w, to_numpy(t), gt, gj, -grid.half_width, grid.spacing,
                                  nb.get_num_threads())
        grad = torch.from_numpy(per_thread.sum(axis=0)).to(dtype=heights.dtype, device=heights.device)
        return grad, None, None, None


def intersect_height_field(heights: torch.Tensor, grid: HeightFieldGrid, origin: torch.Tensor,
                           direction: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """First hit of rays origin + t w (origin: (3,) for all rays or (3, N); w: (3, N), w_z < 0)
    with z = base + S(x, y).

    Returns t (N,) and the surface jet (5, N) = (S_x, S_y, S_xx, S_xy, S_yy) at the hit, both
    differentiable w.r.t. ``heights`` (m, m) (not w.r.t. the rays).
    """
    return _HeightFieldHit.apply(heights, grid, origin, direction)
