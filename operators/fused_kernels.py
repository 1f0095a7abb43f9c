"""Fused native photon kernels: emission, trace, footprint and splat (or its adjoint) per photon.

One numba pass per chunk of photons does what :mod:`operators.emission`,
:mod:`operators.substrate_trace`, :func:`operators.splat.footprint_metric` and
:mod:`operators.splat_kernels` do with torch tensors, without materialising any per-photon array:
``render_photons`` scatters into per-thread images, ``vjp_photons`` recomputes each photon's path,
gathers the splat adjoint, back-propagates it through the optics (hand-written reverse mode,
:mod:`operators.photon_optics`) to the hit's ray parameter and surface jet, and from there into the
16 Catmull-Rom control heights (:func:`operators.heightfield_kernels.hit_adjoint_patch`),
accumulating per-thread gradients. All arithmetic is float64; only the images may be float32.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from operators.catmull_rom import axis_weights, load_patch, scatter_patch
from operators.emission import R2_STEP
from operators.heightfield_kernels import hit_adjoint_patch, solve_hit, surface_jet
from operators.native import FAST_MATH
from operators.photon_optics import (UP, ZERO, add, away_from_zero, footprint_metric, footprint_metric_adjoint,
                                     fresnel, fresnel_adjoint, height_field_normal, height_field_normal_adjoint,
                                     normal_differential, normal_differential_adjoint, passes, refract,
                                     refract_adjoint, transfer, transfer_adjoint)
from operators.splat_kernels import gather_photon, splat_photon


class FusedScene(NamedTuple):
    """Scene constants of the fused kernels (floats in scene units unless stated).

    light_*: light position; half: substrate half width (also the height grid's extent);
    base: substrate thickness (z of d = 0); spacing: height-grid spacing; zlo / zhi: planes that
    bracket the surface, zstart: plane where the hit search starts Newton (HeightFieldGrid.z_planes);
    slope_x, slope_y: bounds on the surface's slopes (HeightFieldGrid.slope_bounds);
    per_channel: photons per channel; flux_scale: P / (4 pi c) A_cell (l_z - h), so
    flux = flux_scale / r^3; radius: emission footprint radius on z = h;
    receiver_z, receiver_half: receiver plane and half width; to_px: pixels per scene unit;
    min_px, max_px: footprint pixel filter and cut-off radii (pixels); fresnel: Fresnel weights.
    """

    light_x: float
    light_y: float
    light_z: float
    half: float
    base: float
    spacing: float
    zlo: float
    zstart: float
    zhi: float
    slope_x: float
    slope_y: float
    per_channel: int
    flux_scale: float
    radius: float
    receiver_z: float
    receiver_half: float
    to_px: float
    min_px: float
    max_px: float
    fresnel: bool


_jit = nb.njit(cache=True, inline="always", fastmath=FAST_MATH, error_model="numpy")


@_jit
def emit(index, sc, shifts):
    """Photon ``index`` (channel-major) as in PointLightEmitter.batch: (channel, w, D_u w, D_v w, flux)."""
    c = index // sc.per_channel
    j = float(index - c * sc.per_channel)
    u = shifts[c, 0] + j * R2_STEP[0]
    v = shifts[c, 1] + j * R2_STEP[1]
    u -= math.floor(u)
    v -= math.floor(v)
    dx = (2.0 * sc.half) * u - sc.half - sc.light_x
    dy = (2.0 * sc.half) * v - sc.half - sc.light_y
    dz = sc.base - sc.light_z
    inv_r = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
    w = (dx * inv_r, dy * inv_r, dz * inv_r)
    s = sc.radius * inv_r
    dwu = (s - w[0] * w[0] * s, -w[1] * w[0] * s, -w[2] * w[0] * s)
    dwv = (-w[0] * w[1] * s, s - w[1] * w[1] * s, -w[2] * w[1] * s)
    return c, w, dwu, dwv, sc.flux_scale * inv_r * inv_r * inv_r


@_jit
def hit_top(d, sc, w, wx, wy, patch, order):
    """Ray parameter t of the first hit on the printed surface and the jet there; leaves the
    weight tables (up to ``order``) and the patch of the hit cell loaded. Returns (t, jet, ix, iy)."""
    m = d.shape[0]
    x0 = -sc.half
    t = solve_hit(d, sc.base, sc.light_x, sc.light_y, sc.light_z, w[0], w[1], w[2], x0, sc.spacing, sc.zlo, sc.zstart,
                  sc.zhi, sc.slope_x, sc.slope_y)
    ix = axis_weights(sc.light_x + t * w[0], x0, sc.spacing, m, order, wx)
    iy = axis_weights(sc.light_y + t * w[1], x0, sc.spacing, m, order, wy)
    load_patch(d, ix, iy, patch)
    return t, surface_jet(patch, wx, wy), ix, iy


@_jit
def through_top(d, sc, shifts, indices, index, wx, wy, patch, order):
    """Photon ``index`` emitted, hit on the printed surface (weight tables up to ``order``) and
    refracted into the glass, with every intermediate the adjoint needs:
    (c, w, Dw, flux, t, jet, ix, iy, n, p1, Dp1, Dn, eta, w1, Dw1, cos_i, cos_t), each D a u, v pair."""
    c, w, dwu, dwv, flux = emit(index, sc, shifts)
    t, jet, ix, iy = hit_top(d, sc, w, wx, wy, patch, order)
    sx, sy, sxx, sxy, syy = jet
    n1 = height_field_normal(sx, sy)
    p1, dpu1, dpv1 = transfer((sc.light_x, sc.light_y, sc.light_z), ZERO, ZERO, w, dwu, dwv, t, n1)
    dnu = normal_differential(sxx, sxy, syy, n1, dpu1)
    dnv = normal_differential(sxx, sxy, syy, n1, dpv1)
    eta = indices[c]
    w1, dwu1, dwv1, ci1, ct1, _ = refract(w, dwu, dwv, n1, dnu, dnv, 1.0 / eta)
    return c, w, dwu, dwv, flux, t, jet, ix, iy, n1, p1, dpu1, dpv1, dnu, dnv, eta, w1, dwu1, dwv1, ci1, ct1


@_jit
def below_top(p1, dpu1, dpv1, w1, dwu1, dwv1, eta, sc):
    """From the top hit to the receiver: (lost, dist2, p2, Dp2, w2, Dw2, cos_i, cos_t, dist3, p3, Dp3)."""
    dist2 = -p1[2] / away_from_zero(w1[2])
    p2, dpu2, dpv2 = transfer(p1, dpu1, dpv1, w1, dwu1, dwv1, dist2, UP)
    w2, dwu2, dwv2, ci2, ct2, k2 = refract(w1, dwu1, dwv1, UP, ZERO, ZERO, eta)
    lost = not (abs(p2[0]) <= sc.half and abs(p2[1]) <= sc.half) or k2 <= 0.0
    dist3 = (sc.receiver_z - p2[2]) / away_from_zero(w2[2])
    p3, dpu3, dpv3 = transfer(p2, dpu2, dpv2, w2, dwu2, dwv2, dist3, UP)
    return lost, dist2, p2, dpu2, dpv2, w2, dwu2, dwv2, ci2, ct2, dist3, p3, dpu3, dpv3


@_jit
def trace_photon(d, sc, shifts, indices, index, wx, wy, patch):
    """Photon ``index`` on the receiver: (channel, px, py, q00, q01, q11, flux) in pixels; flux 0 if lost."""
    (c, _, _, _, flux, _, _, _, _, _, p1, dpu1, dpv1, _, _, eta, w1, dwu1, dwv1, ci1, ct1
     ) = through_top(d, sc, shifts, indices, index, wx, wy, patch, 2)
    lost, _, _, _, _, _, _, _, ci2, ct2, _, p3, dpu3, dpv3 = below_top(p1, dpu1, dpv1, w1, dwu1, dwv1, eta, sc)
    if lost:
        return c, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0
    if sc.fresnel:
        flux *= fresnel(ci1, ct1, 1.0 / eta) * fresnel(ci2, ct2, eta)
    q = footprint_metric(dpu3[0] * sc.to_px, dpu3[1] * sc.to_px, dpv3[0] * sc.to_px, dpv3[1] * sc.to_px,
                         sc.min_px, sc.max_px)
    return (c, (p3[0] + sc.receiver_half) * sc.to_px - 0.5, (p3[1] + sc.receiver_half) * sc.to_px - 0.5,
            q[0], q[1], q[2], flux)


@nb.njit(cache=True, fastmath=FAST_MATH, error_model="numpy")
def _render_range(d, sc, shifts, indices, lo, hi, img, capacity, splat) -> float:
    """Serial body of :func:`render_photons` for photons lo .. hi-1 (one thread, its own image)."""
    wx = np.empty((4, 4))
    wy = np.empty((4, 4))
    patch = np.empty((4, 4))
    buf = np.empty(capacity)
    reached = 0.0
    for index in range(lo, hi):
        c, px, py, q00, q01, q11, flux = trace_photon(d, sc, shifts, indices, index, wx, wy, patch)
        reached += flux
        if splat:
            splat_photon(img, c, px, py, q00, q01, q11, flux, buf)
    return reached


# Photons per block; the host hands blocks to the threads one at a time (parallel_chunksize(1)),
# which balances threads that share a core with other work.
BLOCK = 4096


@nb.njit(parallel=True, cache=True, fastmath=FAST_MATH, error_model="numpy")
def render_photons(d, sc, shifts, indices, start, stop, out, capacity, splat):
    """Splat photons start .. stop-1 into ``out`` (threads, c, n, n) (flux per pixel, sum over
    axis 0 after). ``d`` (m, m) float64 heights, ``shifts`` (c, 2) emission offsets, ``indices``
    (c,) refractive indices, ``capacity`` the pixels of the largest footprint. With ``splat``
    False only the traces run (for timing); returns the total flux that reached the receiver."""
    blocks = (stop - start + BLOCK - 1) // BLOCK
    reached = np.zeros(blocks)
    for b in nb.prange(blocks):
        lo = start + b * BLOCK
        reached[b] = _render_range(d, sc, shifts, indices, lo, min(stop, lo + BLOCK), out[nb.get_thread_id()],
                                   capacity, splat)
    return reached.sum()


@_jit
def photon_vjp(d, sc, shifts, indices, index, padded, pad, wx, wy, patch):
    """Photon ``index``'s contribution to the gradient of <splat, G> w.r.t. the 16 heights around
    its hit, G given with ``pad`` zero pixels on every side (``padded``, see
    :func:`operators.splat_kernels.gather_photon`). Returns (contributes, ix, iy); when it
    contributes, ``patch`` holds the gradient to add at cell (ix, iy) (:func:`scatter_patch`)."""
    (c, w, dwu, dwv, flux0, t, jet, ix, iy, n1, p1, dpu1, dpv1, dnu, dnv, eta, w1, dwu1, dwv1, ci1, ct1
     ) = through_top(d, sc, shifts, indices, index, wx, wy, patch, 3)
    sx, sy, sxx, sxy, syy = jet
    (lost, dist2, p2, dpu2, dpv2, w2, dwu2, dwv2, ci2, ct2, dist3, p3, dpu3, dpv3
     ) = below_top(p1, dpu1, dpv1, w1, dwu1, dwv1, eta, sc)
    if lost:
        return False, ix, iy
    t1 = fresnel(ci1, ct1, 1.0 / eta) if sc.fresnel else 1.0
    t2 = fresnel(ci2, ct2, eta) if sc.fresnel else 1.0
    k = sc.to_px
    fu_x, fu_y, fv_x, fv_y = dpu3[0] * k, dpu3[1] * k, dpv3[0] * k, dpv3[1] * k
    q00, q01, q11 = footprint_metric(fu_x, fu_y, fv_x, fv_y, sc.min_px, sc.max_px)
    g_flux, g_px, g_py, g00, g01, g11 = gather_photon(padded, pad, c, (p3[0] + sc.receiver_half) * k - 0.5,
                                                      (p3[1] + sc.receiver_half) * k - 0.5, q00, q01, q11,
                                                      flux0 * t1 * t2)
    if g_flux == 0.0 and g_px == 0.0 and g_py == 0.0 and g00 == 0.0 and g01 == 0.0 and g11 == 0.0:
        return False, ix, iy
    g_ux, g_uy, g_vx, g_vy = footprint_metric_adjoint(fu_x, fu_y, fv_x, fv_y, sc.min_px, sc.max_px, g00, g01, g11)
    # Receiver plane.
    g_p3 = (g_px * k, g_py * k, 0.0)
    g_dpu2, g_dpv2, g_w2, g_dwu2, g_dwv2, g_dist3, _ = transfer_adjoint(
        dpu2, dpv2, w2, dwu2, dwv2, dist3, UP, g_p3, (g_ux * k, g_uy * k, 0.0), (g_vx * k, g_vy * k, 0.0))
    den3 = away_from_zero(w2[2])
    g_p2 = (g_p3[0], g_p3[1], g_p3[2] - g_dist3 / den3)
    g_w2 = (g_w2[0], g_w2[1], g_w2[2] - g_dist3 * dist3 / den3 * passes(w2[2]))
    # Bottom refraction and transfer.
    g_ci2 = g_ct2 = g_ci1 = g_ct1 = 0.0
    if sc.fresnel:
        g_ci2, g_ct2 = fresnel_adjoint(ci2, ct2, eta, g_flux * flux0 * t1)
        g_ci1, g_ct1 = fresnel_adjoint(ci1, ct1, 1.0 / eta, g_flux * flux0 * t2)
    g_w1, g_dwu1, g_dwv1, _, _, _ = refract_adjoint(w1, dwu1, dwv1, UP, ZERO, ZERO, eta, g_w2, g_dwu2, g_dwv2,
                                                    g_ci2, g_ct2)
    g_dpu1, g_dpv1, g_w1b, g_dwu1b, g_dwv1b, g_dist2, _ = transfer_adjoint(
        dpu1, dpv1, w1, dwu1, dwv1, dist2, UP, g_p2, g_dpu2, g_dpv2)
    den2 = away_from_zero(w1[2])
    g_p1 = (g_p2[0], g_p2[1], g_p2[2] - g_dist2 / den2)
    g_w1 = add(g_w1, g_w1b)
    g_w1 = (g_w1[0], g_w1[1], g_w1[2] - g_dist2 * dist2 / den2 * passes(w1[2]))
    # Top refraction, normal differential, top transfer, normal.
    _, _, _, g_n1, g_dnu, g_dnv = refract_adjoint(w, dwu, dwv, n1, dnu, dnv, 1.0 / eta, g_w1,
                                                  add(g_dwu1, g_dwu1b), add(g_dwv1, g_dwv1b), g_ci1, g_ct1)
    g_sxx, g_sxy, g_syy, g_nu, g_dpu = normal_differential_adjoint(sxx, sxy, syy, n1, dpu1, g_dnu)
    g_sxx2, g_sxy2, g_syy2, g_nv, g_dpv = normal_differential_adjoint(sxx, sxy, syy, n1, dpv1, g_dnv)
    _, _, _, _, _, g_t, g_nt = transfer_adjoint(ZERO, ZERO, w, dwu, dwv, t, n1, g_p1, add(g_dpu1, g_dpu),
                                                add(g_dpv1, g_dpv))
    g_sx, g_sy = height_field_normal_adjoint(sx, sy, add(add(g_n1, g_nu), add(g_nv, g_nt)))
    hit_adjoint_patch(wx, wy, patch, w[0], w[1], w[2], g_t, g_sx, g_sy, g_sxx + g_sxx2, g_sxy + g_sxy2,
                      g_syy + g_syy2)
    return True, ix, iy


@nb.njit(cache=True, fastmath=FAST_MATH, error_model="numpy")
def _vjp_range(d, sc, shifts, indices, lo, hi, padded, pad, grad) -> None:
    """Serial body of :func:`vjp_photons` for photons lo .. hi-1 (one thread, its own gradient)."""
    wx = np.empty((4, 4))
    wy = np.empty((4, 4))
    patch = np.empty((4, 4))
    for index in range(lo, hi):
        contributes, ix, iy = photon_vjp(d, sc, shifts, indices, index, padded, pad, wx, wy, patch)
        if contributes:
            scatter_patch(grad, ix, iy, patch)


@nb.njit(parallel=True, cache=True, fastmath=FAST_MATH, error_model="numpy")
def vjp_photons(d, sc, shifts, indices, start, stop, padded, pad, out):
    """Add to ``out`` (threads, m, m) the gradient w.r.t. d of <splat of photons start .. stop-1,
    G> (G (c, n, n), per pixel flux, given as ``padded`` float64 with ``pad`` zero pixels on every
    side: :func:`operators.splat_kernels.pad_for_gather`); sum over axis 0 after."""
    blocks = (stop - start + BLOCK - 1) // BLOCK
    for b in nb.prange(blocks):
        lo = start + b * BLOCK
        _vjp_range(d, sc, shifts, indices, lo, min(stop, lo + BLOCK), padded, pad,
                   out[nb.get_thread_id()])
