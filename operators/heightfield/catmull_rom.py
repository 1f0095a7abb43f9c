"""Bicubic Catmull-Rom interpolation of a height field, compiled with numba.

The surface S(x, y) interpolates the samples d[row, col] = d(y_row, x_col) on the regular grid
x_col = x0 + col * spacing (likewise y). It is C1 (continuous normals, no faceting) and, cell by
cell, a bicubic polynomial, so every derivative used by photon differentials (the Hessian) and by
their adjoint (third derivatives) is exact. Samples beyond the border are replicated, and the
surface is held flat beyond the outer grid lines. S is linear in d: S(x, y) = sum_ij B_ij(x, y)
d_ij with tensor-product weights B_ij(x, y) = b_i(y) b_j(x).

Kernels work on a 4 x 4 patch of samples (nodes i-1 .. i+2 around the cell) and on weight
tables w[k, a] of the k-th derivative along one axis; no array slicing in the hot loops.
"""

from __future__ import annotations

import math

import numpy as np

from operators.kernels.numba_settings import jit_call


@jit_call
def _fill_basis(s: float, k: int, scale: float, w: np.ndarray) -> None:
    """Row k of the weight table: k-th s-derivative of the Catmull-Rom weights times ``scale``."""
    s2 = s * s
    s3 = s2 * s
    if k == 0:
        w[0, 0] = 0.5 * (-s3 + 2.0 * s2 - s)
        w[0, 1] = 0.5 * (3.0 * s3 - 5.0 * s2 + 2.0)
        w[0, 2] = 0.5 * (-3.0 * s3 + 4.0 * s2 + s)
        w[0, 3] = 0.5 * (s3 - s2)
    elif k == 1:
        w[1, 0] = scale * 0.5 * (-3.0 * s2 + 4.0 * s - 1.0)
        w[1, 1] = scale * 0.5 * (9.0 * s2 - 10.0 * s)
        w[1, 2] = scale * 0.5 * (-9.0 * s2 + 8.0 * s + 1.0)
        w[1, 3] = scale * 0.5 * (3.0 * s2 - 2.0 * s)
    elif k == 2:
        w[2, 0] = scale * (-3.0 * s + 2.0)
        w[2, 1] = scale * (9.0 * s - 5.0)
        w[2, 2] = scale * (-9.0 * s + 4.0)
        w[2, 3] = scale * (3.0 * s - 1.0)
    else:
        w[3, 0] = scale * -3.0
        w[3, 1] = scale * 9.0
        w[3, 2] = scale * -9.0
        w[3, 3] = scale * 3.0


@jit_call
def axis_weights(coord: float, origin: float, spacing: float, m: int, max_order: int, w: np.ndarray) -> int:
    """Fill w[k, :] (k <= max_order) with the weights of the k-th derivative at ``coord``.

    Derivatives are in scene units (divided by spacing**k) and zero off the grid, where the
    surface is flat. Returns the cell index i (the patch spans nodes i-1 .. i+2).
    """
    g = (coord - origin) / spacing
    inside = 0.0 <= g <= m - 1.0
    g = min(max(g, 0.0), m - 1.0)
    i = min(int(math.floor(g)), m - 2)
    s = g - i
    scale = 1.0
    for k in range(max_order + 1):
        _fill_basis(s, k, scale if inside else 0.0, w)
        scale /= spacing
    return i


@jit_call
def _cell(coord: float, origin: float, spacing: float, m: int) -> tuple[int, float, float]:
    """(cell index i, offset s in [0, 1], d/dcoord scale: 1 / spacing on the grid, 0 off it)."""
    g = (coord - origin) / spacing
    inside = 0.0 <= g <= m - 1.0
    g = min(max(g, 0.0), m - 1.0)
    i = min(int(math.floor(g)), m - 2)
    return i, g - i, (1.0 / spacing if inside else 0.0)


@jit_call
def _basis(s: float, k: float) -> tuple[float, float, float, float, float, float, float, float]:
    """Catmull-Rom weights at s and their s-derivatives times k (rows 0 and 1 of _fill_basis)."""
    s2 = s * s
    s3 = s2 * s
    return (0.5 * (-s3 + 2.0 * s2 - s), 0.5 * (3.0 * s3 - 5.0 * s2 + 2.0), 0.5 * (-3.0 * s3 + 4.0 * s2 + s),
            0.5 * (s3 - s2), k * 0.5 * (-3.0 * s2 + 4.0 * s - 1.0), k * 0.5 * (9.0 * s2 - 10.0 * s),
            k * 0.5 * (-9.0 * s2 + 8.0 * s + 1.0), k * 0.5 * (3.0 * s2 - 2.0 * s))


@jit_call
def surface_gradient(d: np.ndarray, x: float, y: float, origin: float, spacing: float
                     ) -> tuple[float, float, float]:
    """(S, S_x, S_y) at (x, y): the same values as axis_weights / load_patch / contract, in
    scalar code (no weight tables), for the hit solver's inner loop."""
    m = d.shape[0]
    ix, sx, kx = _cell(x, origin, spacing, m)
    iy, sy, ky = _cell(y, origin, spacing, m)
    a0, a1, a2, a3, b0, b1, b2, b3 = _basis(sx, kx)
    e0, e1, e2, e3, f0, f1, f2, f3 = _basis(sy, ky)
    c0, c1, c2, c3 = max(ix - 1, 0), ix, ix + 1, min(ix + 2, m - 1)
    value = slope_x = slope_y = 0.0
    for a in range(4):
        r = clamped_node(iy - 1 + a, m)
        d0, d1, d2, d3 = d[r, c0], d[r, c1], d[r, c2], d[r, c3]
        v = a0 * d0 + a1 * d1 + a2 * d2 + a3 * d3
        ey = e0 if a == 0 else e1 if a == 1 else e2 if a == 2 else e3
        value += ey * v
        slope_x += ey * (b0 * d0 + b1 * d1 + b2 * d2 + b3 * d3)
        slope_y += (f0 if a == 0 else f1 if a == 1 else f2 if a == 2 else f3) * v
    return value, slope_x, slope_y


@jit_call
def _curvature_basis(s: float, k2: float) -> tuple[float, float, float, float]:
    """Second s-derivatives of the Catmull-Rom weights times k2 (row 2 of _fill_basis)."""
    return k2 * (-3.0 * s + 2.0), k2 * (9.0 * s - 5.0), k2 * (-9.0 * s + 4.0), k2 * (3.0 * s - 1.0)


@jit_call
def surface_jet_at(d: np.ndarray, x: float, y: float, origin: float, spacing: float
                   ) -> tuple[float, float, float, float, float]:
    """(S_x, S_y, S_xx, S_xy, S_yy) at (x, y): the values that weight tables (axis_weights,
    load_patch, contract) give, in scalar code, for the hit searches' surface jet."""
    m = d.shape[0]
    ix, sx, kx = _cell(x, origin, spacing, m)
    iy, sy, ky = _cell(y, origin, spacing, m)
    a0, a1, a2, a3, b0, b1, b2, b3 = _basis(sx, kx)
    c0, c1, c2, c3 = _curvature_basis(sx, kx * kx)
    e0, e1, e2, e3, f0, f1, f2, f3 = _basis(sy, ky)
    g0, g1, g2, g3 = _curvature_basis(sy, ky * ky)
    n0, n1, n2, n3 = max(ix - 1, 0), ix, ix + 1, min(ix + 2, m - 1)
    s_x = s_y = s_xx = s_xy = s_yy = 0.0
    for a in range(4):
        r = clamped_node(iy - 1 + a, m)
        d0, d1, d2, d3 = d[r, n0], d[r, n1], d[r, n2], d[r, n3]
        v = a0 * d0 + a1 * d1 + a2 * d2 + a3 * d3
        vx = b0 * d0 + b1 * d1 + b2 * d2 + b3 * d3
        vxx = c0 * d0 + c1 * d1 + c2 * d2 + c3 * d3
        ey = e0 if a == 0 else e1 if a == 1 else e2 if a == 2 else e3
        fy = f0 if a == 0 else f1 if a == 1 else f2 if a == 2 else f3
        gy = g0 if a == 0 else g1 if a == 1 else g2 if a == 2 else g3
        s_x += ey * vx
        s_xx += ey * vxx
        s_y += fy * v
        s_xy += fy * vx
        s_yy += gy * v
    return s_x, s_y, s_xx, s_xy, s_yy


@jit_call
def clamped_node(i: int, m: int) -> int:
    """The grid index i clamped to 0 .. m - 1 (the edge sample repeats outside the grid)."""
    return min(max(i, 0), m - 1)


@jit_call
def load_patch(d: np.ndarray, ix: int, iy: int, patch: np.ndarray) -> None:
    """patch[a, b] = d[iy-1+a, ix-1+b] with replicated borders."""
    m = d.shape[0]
    for a in range(4):
        r = clamped_node(iy - 1 + a, m)
        for b in range(4):
            patch[a, b] = d[r, clamped_node(ix - 1 + b, m)]


@jit_call
def contract(patch: np.ndarray, wx: np.ndarray, kx: int, wy: np.ndarray, ky: int) -> float:
    """d^(kx+ky) S / dx^kx dy^ky = sum_ab wy[ky, a] wx[kx, b] patch[a, b]."""
    acc = 0.0
    for a in range(4):
        row = wx[kx, 0] * patch[a, 0] + wx[kx, 1] * patch[a, 1] + wx[kx, 2] * patch[a, 2] + wx[kx, 3] * patch[a, 3]
        acc += wy[ky, a] * row
    return acc


@jit_call
def scatter_patch(grad: np.ndarray, ix: int, iy: int, patch: np.ndarray) -> None:
    """Adjoint of :func:`load_patch`: grad[iy-1+a, ix-1+b] += patch[a, b]."""
    m = grad.shape[0]
    for a in range(4):
        r = clamped_node(iy - 1 + a, m)
        for b in range(4):
            grad[r, clamped_node(ix - 1 + b, m)] += patch[a, b]


def refinement_matrix(m: int, k: int) -> np.ndarray:
    """(k (m - 1) + 1, m): the surface's values at k points per cell along one axis (the grid
    lines and k - 1 points between each pair) as weights of the m samples, borders replicated as
    the kernels do; S on the fine grid is R d R^T."""
    fine = np.arange(k * (m - 1) + 1) / k
    cell = np.minimum(fine.astype(np.int64), m - 2)
    s = fine - cell
    s2, s3 = s * s, s * s * s
    weights = 0.5 * np.stack([-s3 + 2.0 * s2 - s, 3.0 * s3 - 5.0 * s2 + 2.0, -3.0 * s3 + 4.0 * s2 + s, s3 - s2], 1)
    matrix = np.zeros((fine.size, m))
    rows = np.arange(fine.size)
    for a in range(4):
        np.add.at(matrix, (rows, np.clip(cell - 1 + a, 0, m - 1)), weights[:, a])
    return matrix


def refined_surface(d: np.ndarray, refine: int) -> tuple[np.ndarray, np.ndarray | None]:
    """The surface of heights d (m, m) at ``refine`` points per cell along each axis, and at the
    centres of those fine cells: (k (m - 1) + 1 square, k (m - 1) square) with k = refine; for
    refine 1 the samples themselves and None."""
    if refine == 1:
        return d, None
    matrix = refinement_matrix(d.shape[0], 2 * refine)
    dense = matrix @ d @ matrix.T
    return dense[::2, ::2], dense[1::2, 1::2]
