"""Native (numba, multi-threaded) kernels: ray / height-field intersection and its adjoint.

A photon leaves ``origin`` along the unit direction w (w_z < 0) and first meets the surface
z = base + S(x, y), S the Catmull-Rom interpolant of the heights d (see :mod:`catmull_rom`).
The forward kernel returns the ray parameter t of that hit and the surface jet there,
(S_x, S_y, S_xx, S_xy, S_yy); the backward kernel returns the gradient w.r.t. d of any loss
through (t, jet), including the motion of the hit point (implicit function theorem):
dt/dd_ij = B_ij(u) / (w_z - grad S . w_xy).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from operators.heightfield.catmull_rom import (axis_weights, contract, load_patch, scatter_patch, surface_gradient,
                                               surface_jet_at)
from operators.kernels.numba_settings import jit_call, jit_inline, jit_parallel

MAX_MARCH_STEPS = 512
NEWTON_ITERATIONS = 40
SETTLE = 1e-8  # Newton step (relative to the z scale) below which the next step is taken unchecked


@jit_call
def _needs_march(wx_, wy_, wz_, slope_x, slope_y) -> bool:
    """Whether the gap may rise again along the ray (see :func:`solve_hit`)."""
    return not slope_x * abs(wx_) + slope_y * abs(wy_) < abs(wz_)


@jit_call
def _gap(d, base, ox, oy, oz, wx_, wy_, wz_, x0, spacing, t) -> tuple[float, float]:
    """(gap, d gap / dt) at ray parameter t: the ray's height above the surface and its slope."""
    s, sx, sy = surface_gradient(d, ox + t * wx_, oy + t * wy_, x0, spacing)
    return oz + t * wz_ - base - s, wz_ - sx * wx_ - sy * wy_


@jit_call
def _newton_update(t, g, slope, lo, hi, settle) -> tuple[float, float, float, bool]:
    """One safeguarded Newton step from t (gap g, its slope) inside the bracket lo .. hi:
    (next t, lo, hi, settled), settled when the step fell below ``settle``."""
    if g > 0.0:
        lo = t
    else:
        hi = t
    t_new = t - g / slope if slope != 0.0 else 0.5 * (lo + hi)
    if not (lo <= t_new <= hi):
        return 0.5 * (lo + hi), lo, hi, False
    return t_new, lo, hi, abs(t_new - t) <= settle


@jit_call
def _tolerances(oz, zhi) -> tuple[float, float]:
    """(gap within rounding, settling step) of the Newton iteration, relative to the z scale."""
    z_scale = abs(oz) + abs(zhi) + 1.0
    return 1e-12 * z_scale, SETTLE * z_scale


@jit_call
def solve_hit(d, base, ox, oy, oz, wx_, wy_, wz_, x0, spacing, zlo, zstart, zhi, slope_x, slope_y) -> float:
    """First root of the gap (ray height above the surface): march between the bounding planes
    zhi and zlo in half-cell steps, then Newton safeguarded by bisection inside the bracket,
    started at the first crossing the march found or, if it found none, at the plane zstart.
    The march is skipped where the gap provably falls monotonically along the ray (its only root
    is the first): slope_x |w_x| + slope_y |w_y| < |w_z| for bounds slope_x >= |S_x|,
    slope_y >= |S_y| (HeightFieldGrid.slope_bounds).

    Newton stops when the gap is within rounding or its step falls below SETTLE (relative to
    the scene's z scale): convergence is quadratic there, so the step it takes is accurate to
    about SETTLE^2 and needs no further evaluation of the surface.
    """
    t_a = (zhi - oz) / wz_
    t_b = (zlo - oz) / wz_
    travel = math.sqrt(wx_ * wx_ + wy_ * wy_) * (t_b - t_a)
    steps = int(min(max(math.ceil(travel / (0.5 * spacing)), 1.0), MAX_MARCH_STEPS))
    if not _needs_march(wx_, wy_, wz_, slope_x, slope_y):
        steps = 1
    dt = (t_b - t_a) / steps
    lo, hi = t_a, t_b
    known = False  # whether (g, slope) below already belong to t
    g = slope = 0.0
    for k in range(1, steps):
        t_k = t_a + k * dt
        g, slope = _gap(d, base, ox, oy, oz, wx_, wy_, wz_, x0, spacing, t_k)
        if g <= 0.0:
            hi = t_k
            known = True
            break
        lo = t_k
    t = hi if known else min(max((zstart - oz) / wz_, lo), hi)
    tol, settle = _tolerances(oz, zhi)
    for _ in range(NEWTON_ITERATIONS):
        if not known:
            g, slope = _gap(d, base, ox, oy, oz, wx_, wy_, wz_, x0, spacing, t)
        known = False
        if abs(g) <= tol:
            break
        t, lo, hi, settled = _newton_update(t, g, slope, lo, hi, settle)
        if settled:
            break
    return t


@jit_call
def packet_gaps(d, base, ox, oy, oz, dirs, count, x0, spacing, t, search) -> None:
    """(gap, d gap / dt) (:func:`_gap`) of the rays k < count along dirs[0:3, k] at t[k] whose
    search[2, k] is not 0, into search[3, k] and search[4, k]: independent surface evaluations in
    one loop, which the out-of-order core overlaps."""
    for k in range(count):
        if search[2, k] != 0.0:
            search[3, k], search[4, k] = _gap(d, base, ox, oy, oz, dirs[0, k], dirs[1, k], dirs[2, k], x0, spacing,
                                              t[k])


@jit_call
def solve_hits(d, base, ox, oy, oz, dirs, count, x0, spacing, zlo, zstart, zhi, slope_x, slope_y, t_out,
               search) -> None:
    """:func:`solve_hit` for the rays along dirs[0:3, k], k < count, into t_out[k], with the
    Newton iterations of all rays that need no march in lockstep: each round steps every ray
    not yet converged, so the out-of-order core overlaps the rays' surface evaluations instead of
    waiting on one ray's chain of dependent steps (8-25% faster on the built-in shapes).
    ``search`` (5, >= count) is scratch: the brackets, whether a ray is still iterating, and its
    gap and slope (:func:`packet_gaps`, each round's surface evaluations)."""
    tol, settle = _tolerances(oz, zhi)
    for k in range(count):
        wx_, wy_, wz_ = dirs[0, k], dirs[1, k], dirs[2, k]
        if _needs_march(wx_, wy_, wz_, slope_x, slope_y):
            t_out[k] = solve_hit(d, base, ox, oy, oz, wx_, wy_, wz_, x0, spacing, zlo, zstart, zhi, slope_x, slope_y)
            search[2, k] = 0.0
        else:
            lo = (zhi - oz) / wz_
            hi = (zlo - oz) / wz_
            search[0, k], search[1, k], search[2, k] = lo, hi, 1.0
            t_out[k] = min(max((zstart - oz) / wz_, lo), hi)
    for _ in range(NEWTON_ITERATIONS):
        packet_gaps(d, base, ox, oy, oz, dirs, count, x0, spacing, t_out, search)
        iterating = 0
        for k in range(count):
            if search[2, k] == 0.0:
                continue
            t, g, slope = t_out[k], search[3, k], search[4, k]
            settled = abs(g) <= tol
            if not settled:
                t_out[k], search[0, k], search[1, k], settled = _newton_update(t, g, slope, search[0, k],
                                                                                search[1, k], settle)
            if settled:
                search[2, k] = 0.0
            else:
                iterating += 1
        if iterating == 0:
            break


@jit_inline
def surface_derivatives(patch, wx, wy):
    """(S_x, S_y, S_xx, S_xy, S_yy, S_xxx, S_xxy, S_xyy, S_yyy) of the surface of the samples
    ``patch`` (4, 4) at the point of the weight tables of order 3, wx / wy."""
    return (contract(patch, wx, 1, wy, 0), contract(patch, wx, 0, wy, 1), contract(patch, wx, 2, wy, 0),
            contract(patch, wx, 1, wy, 1), contract(patch, wx, 0, wy, 2), contract(patch, wx, 3, wy, 0),
            contract(patch, wx, 2, wy, 1), contract(patch, wx, 1, wy, 2), contract(patch, wx, 0, wy, 3))


@jit_call
def hit_adjoint_patch(wx, wy, patch, wx_, wy_, wz_, g_t, g_sx, g_sy, g_sxx, g_sxy, g_syy) -> None:
    """Overwrite ``patch`` (the samples around one photon's hit) with the gradient of
    g_t t + <g_jet, jet> w.r.t. those samples (add it into the heights with :func:`scatter_patch`).

    wx / wy are weight tables of order 3 at the hit, (wx_, wy_, wz_) the ray direction.
    """
    sx, sy, sxx, sxy, syy, sxxx, sxxy, sxyy, syyy = surface_derivatives(patch, wx, wy)
    # Loss change per unit of t while d is held: the hit point slides along the ray.
    along = (g_t
             + g_sx * (sxx * wx_ + sxy * wy_) + g_sy * (sxy * wx_ + syy * wy_)
             + g_sxx * (sxxx * wx_ + sxxy * wy_) + g_sxy * (sxxy * wx_ + sxyy * wy_)
             + g_syy * (sxyy * wx_ + syyy * wy_))
    c = along / (wz_ - sx * wx_ - sy * wy_)
    for a in range(4):
        for b in range(4):
            patch[a, b] = (wy[0, a] * (c * wx[0, b] + g_sx * wx[1, b] + g_sxx * wx[2, b])
                           + wy[1, a] * (g_sy * wx[0, b] + g_sxy * wx[1, b])
                           + wy[2, a] * g_syy * wx[0, b])


@jit_call
def scatter_hit_adjoint(grad, ix, iy, wx, wy, patch, wx_, wy_, wz_, g_t, g_sx, g_sy, g_sxx, g_sxy, g_syy) -> None:
    """Add to grad (m, m) the gradient w.r.t. d of g_t t + <g_jet, jet> at one photon's hit
    (:func:`hit_adjoint_patch`, then scattered into the cell's samples; ``patch`` is overwritten)."""
    hit_adjoint_patch(wx, wy, patch, wx_, wy_, wz_, g_t, g_sx, g_sy, g_sxx, g_sxy, g_syy)
    scatter_patch(grad, ix, iy, patch)


@jit_parallel
def hit_forward(d, base, origins, dirs, x0, spacing, zlo, zstart, zhi, slope_x, slope_y, t_out, jet_out, nthreads):
    """Fill t_out (N,) and jet_out (5, N) = (S_x, S_y, S_xx, S_xy, S_yy) at the hit of each ray
    origins[:, p] + t dirs[:, p] (:func:`solve_hit`)."""
    n = dirs.shape[1]
    per = (n + nthreads - 1) // nthreads
    for th in nb.prange(nthreads):
        for p in range(th * per, min(n, (th + 1) * per)):
            wx_, wy_, wz_ = dirs[0, p], dirs[1, p], dirs[2, p]
            ox, oy, oz = origins[0, p], origins[1, p], origins[2, p]
            t = solve_hit(d, base, ox, oy, oz, wx_, wy_, wz_, x0, spacing, zlo, zstart, zhi, slope_x, slope_y)
            t_out[p] = t
            jet = surface_jet_at(d, ox + t * wx_, oy + t * wy_, x0, spacing)
            for k in range(5):
                jet_out[k, p] = jet[k]


@jit_parallel
def hit_backward(d, origins, dirs, t, grad_t, grad_jet, x0, spacing, nthreads):
    """Gradient (nthreads, m, m) w.r.t. d of <grad_t, t> + <grad_jet, jet>; sum over axis 0."""
    n = dirs.shape[1]
    m = d.shape[0]
    out = np.zeros((nthreads, m, m))
    per = (n + nthreads - 1) // nthreads
    for th in nb.prange(nthreads):
        wx = np.empty((4, 4))
        wy = np.empty((4, 4))
        patch = np.empty((4, 4))
        grad = out[th]
        for p in range(th * per, min(n, (th + 1) * per)):
            wx_, wy_, wz_ = dirs[0, p], dirs[1, p], dirs[2, p]
            ix = axis_weights(origins[0, p] + t[p] * wx_, x0, spacing, m, 3, wx)
            iy = axis_weights(origins[1, p] + t[p] * wy_, x0, spacing, m, 3, wy)
            load_patch(d, ix, iy, patch)
            scatter_hit_adjoint(grad, ix, iy, wx, wy, patch, wx_, wy_, wz_, grad_t[p], grad_jet[0, p],
                                grad_jet[1, p], grad_jet[2, p], grad_jet[3, p], grad_jet[4, p])
    return out
