"""The reverse pass of the fused height-field kernels (:mod:`operators.heightfield.kernels_native`):
``vjp_photons`` recomputes each photon's path, gathers the splat adjoint, back-propagates it through
the optics (hand-written reverse mode, :mod:`operators.optics.native`) to the hit's ray parameter
and surface jet, and from there into the 16 Catmull-Rom control heights
(:func:`operators.heightfield.intersect_native.hit_adjoint_patch`), accumulating per-thread
gradients. All arithmetic is float64.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from operators.heightfield.catmull_rom import scatter_patch
from operators.heightfield.intersect_native import hit_adjoint_patch
from operators.heightfield.kernels_native import (BLOCK, PACKET, emit, hit_cell, hit_jet, load_hit, optics_state,
                                                  splat_arguments, trace_packet)
from operators.kernels.numba_settings import jit_call, jit_inline, jit_parallel
from operators.kernels.simd import data_pointer, hit_adjoint
from operators.optics.native import (UP, ZERO, add, away_from_zero, axpy, dot, footprint_metric_adjoint, fresnel,
                                     fresnel_adjoint, height_field_normal_adjoint, normal_differential_adjoint, passes,
                                     refract_adjoint, transfer_adjoint)
from operators.splat.native import gather_photon, gather_photon_simd

__all__ = ["optics_adjoint", "photon_vjp", "vjp_range", "vjp_photons"]


@jit_inline
def optics_adjoint(sc, w, dwu, dwv, flux0, t, jet, eta, state, g_flux, g_px, g_py, g00, g01, g11):
    """Reverse mode through the optics: gradients of a loss with the given gradients w.r.t. the
    splat arguments (:func:`splat_arguments`) back to the hit, (g_t, g_sx, g_sy, g_sxx, g_sxy, g_syy)."""
    sx, sy, sxx, sxy, syy = jet
    top, below, fu, fv = state
    n1, p1, dpu1, dpv1, dnu, dnv, w1, dwu1, dwv1, ci1, ct1 = top
    _, dist2, p2, dpu2, dpv2, w2, dwu2, dwv2, ci2, ct2, dist3, p3, dpu3, dpv3, n2, fx, fy, _ = below
    t1 = fresnel(ci1, ct1, 1.0 / eta) if sc.fresnel else 1.0
    t2 = fresnel(ci2, ct2, eta) if sc.fresnel else 1.0
    k = sc.to_px
    g_ux, g_uy, g_vx, g_vy = footprint_metric_adjoint(fu[0], fu[1], fv[0], fv[1], sc.min_px, sc.max_px,
                                                      g00, g01, g11)
    # Receiver plane (the walls' mirror undone: x -> fx x + ox, y likewise).
    g_p3 = (g_px * k * fx, g_py * k * fy, 0.0)
    g_dpu2, g_dpv2, g_w2, g_dwu2, g_dwv2, g_dist3, _ = transfer_adjoint(
        dpu2, dpv2, w2, dwu2, dwv2, dist3, UP, g_p3, (g_ux * k * fx, g_uy * k * fy, 0.0),
        (g_vx * k * fx, g_vy * k * fy, 0.0))
    den3 = away_from_zero(w2[2])
    g_p2 = (g_p3[0], g_p3[1], g_p3[2] - g_dist3 / den3)
    g_w2 = (g_w2[0], g_w2[1], g_w2[2] - g_dist3 * dist3 / den3 * passes(w2[2]))
    # Refraction and transfer at the face the photon leaves through (the bottom or a wall, n2).
    g_ci2 = g_ct2 = g_ci1 = g_ct1 = 0.0
    if sc.fresnel:
        g_ci2, g_ct2 = fresnel_adjoint(ci2, ct2, eta, g_flux * flux0 * t1)
        g_ci1, g_ct1 = fresnel_adjoint(ci1, ct1, 1.0 / eta, g_flux * flux0 * t2)
    g_w1, g_dwu1, g_dwv1, _, _, _ = refract_adjoint(w1, dwu1, dwv1, n2, ZERO, ZERO, eta, g_w2, g_dwu2, g_dwv2,
                                                    g_ci2, g_ct2)
    g_dpu1, g_dpv1, g_w1b, g_dwu1b, g_dwv1b, g_dist2, _ = transfer_adjoint(
        dpu1, dpv1, w1, dwu1, dwv1, dist2, n2, g_p2, g_dpu2, g_dpv2)
    wn2 = dot(w1, n2)
    den2 = away_from_zero(wn2)
    g_p1 = axpy(-g_dist2 / den2, n2, g_p2)
    g_w1 = axpy(-g_dist2 * dist2 / den2 * passes(wn2), n2, add(g_w1, g_w1b))
    # Top refraction, normal differential, top transfer, normal.
    _, _, _, g_n1, g_dnu, g_dnv = refract_adjoint(w, dwu, dwv, n1, dnu, dnv, 1.0 / eta, g_w1,
                                                  add(g_dwu1, g_dwu1b), add(g_dwv1, g_dwv1b), g_ci1, g_ct1)
    g_sxx, g_sxy, g_syy, g_nu, g_dpu = normal_differential_adjoint(sxx, sxy, syy, n1, dpu1, g_dnu)
    g_sxx2, g_sxy2, g_syy2, g_nv, g_dpv = normal_differential_adjoint(sxx, sxy, syy, n1, dpv1, g_dnv)
    _, _, _, _, _, g_t, g_nt = transfer_adjoint(ZERO, ZERO, w, dwu, dwv, t, n1, g_p1, add(g_dpu1, g_dpu),
                                                add(g_dpv1, g_dpv))
    g_sx, g_sy = height_field_normal_adjoint(sx, sy, add(add(g_n1, g_nu), add(g_nv, g_nt)))
    return g_t, g_sx, g_sy, g_sxx + g_sxx2, g_sxy + g_sxy2, g_syy + g_syy2


@jit_inline
def _contributes(g) -> bool:
    """Whether a photon's splat-adjoint gradients (:func:`gather_photon`) are not all zero."""
    return not (g[0] == 0.0 and g[1] == 0.0 and g[2] == 0.0 and g[3] == 0.0 and g[4] == 0.0 and g[5] == 0.0)


@jit_inline
def photon_vjp(d, sc, shifts, indices, index, padded, pad, wx, wy, patch):
    """Photon ``index``'s contribution to the gradient of <splat, G> w.r.t. the 16 heights around
    its hit, G given with ``pad`` zero pixels on every side (``padded``, see
    :func:`operators.splat.native.gather_photon`). Returns (contributes, ix, iy); when it
    contributes, ``patch`` holds the gradient to add at cell (ix, iy) (:func:`scatter_patch`),
    and wx / wy the weight tables there."""
    c, w, dwu, dwv, flux = emit(index, sc, shifts)
    t, jet = hit_jet(d, sc, w)
    eta = indices[c]
    state = optics_state(sc, w, dwu, dwv, t, jet, eta)
    px, py, q00, q01, q11, f = splat_arguments(sc, flux, eta, state)
    g = gather_photon(padded, pad, c, px, py, q00, q01, q11, f)
    if not _contributes(g):
        return False, 0, 0
    g_t, g_sx, g_sy, g_sxx, g_sxy, g_syy = optics_adjoint(sc, w, dwu, dwv, flux, t, jet, eta, state, g[0], g[1], g[2],
                                                          g[3], g[4], g[5])
    ix, iy = hit_cell(d, sc, w, t, wx, wy, patch)
    hit_adjoint_patch(wx, wy, patch, w[0], w[1], w[2], g_t, g_sx, g_sy, g_sxx, g_sxy, g_syy)
    return True, ix, iy


@jit_call
def vjp_range(d, sc, shifts, indices, lo, hi, padded, pad, grad, hit_t, t_first) -> None:
    """One thread's share of :func:`vjp_photons`: photons lo .. hi-1 into its own gradient ``grad`` (m, m);
    packets of PACKET photons traced by :func:`trace_packet` (replaying the hits in ``hit_t``
    unless it is empty), the splat-adjoint gathers and height scatters photon by photon, the
    optics and their adjoint as loops over the packet that LLVM vectorises."""
    wx = np.empty((4, 4))
    wy = np.empty((4, 4))
    patch = np.empty((4, 4))
    hits = np.empty((17, PACKET))  # per photon: w, Dw_u, Dw_v, flux, t, jet, eta
    search = np.empty((5, PACKET))  # the hit search's brackets, state, gaps and slopes
    channel = np.empty(PACKET, dtype=np.int64)
    spots = np.empty((6, PACKET))  # per photon: splat arguments, then their gradients
    sums = np.empty(12)  # the AVX2 gather's sums
    for first in range(lo, hi, PACKET):
        count = min(PACKET, hi - first)
        trace_packet(d, sc, shifts, indices, first, count, hits, channel, spots, search, hit_t, t_first,
                     hit_t.shape[0] > 0)
        for k in range(count):
            g = gather_photon_simd(padded, pad, channel[k], spots[0, k], spots[1, k], spots[2, k], spots[3, k],
                                   spots[4, k], spots[5, k], sc.simd, sums)
            for j in range(6):
                spots[j, k] = g[j]
        for k in range(count):
            w, dwu, dwv, flux, t, jet, eta = load_hit(hits, k)
            g_hit = optics_adjoint(sc, w, dwu, dwv, flux, t, jet, eta, optics_state(sc, w, dwu, dwv, t, jet, eta),
                                   spots[0, k], spots[1, k], spots[2, k], spots[3, k], spots[4, k], spots[5, k])
            for j in range(6):
                hits[11 + j, k] = g_hit[j]  # jet and eta are no longer needed
        for k in range(count):
            if not _contributes((spots[0, k], spots[1, k], spots[2, k], spots[3, k], spots[4, k], spots[5, k])):
                continue
            w = (hits[0, k], hits[1, k], hits[2, k])
            if sc.simd:
                hit_adjoint(data_pointer(d), data_pointer(grad), d.shape[0], sc.light_x + hits[10, k] * w[0],
                            sc.light_y + hits[10, k] * w[1], -sc.half, 1.0 / sc.spacing, w[0], w[1], w[2], hits[11, k],
                            hits[12, k], hits[13, k], hits[14, k], hits[15, k], hits[16, k])
                continue
            ix, iy = hit_cell(d, sc, w, hits[10, k], wx, wy, patch)
            hit_adjoint_patch(wx, wy, patch, w[0], w[1], w[2], hits[11, k], hits[12, k], hits[13, k], hits[14, k],
                              hits[15, k], hits[16, k])
            scatter_patch(grad, ix, iy, patch)


@jit_parallel
def vjp_photons(d, sc, shifts, indices, start, stop, padded, pad, out, hit_t):
    """Add to ``out`` (threads, m, m) the gradient w.r.t. d of <splat of photons start .. stop-1,
    G> (G (c, n, n), per pixel flux, given as ``padded`` float64 with ``pad`` zero pixels on every
    side: :func:`operators.splat.native.pad_for_gather`); sum over axis 0 after. ``hit_t``
    (stop - start,): the hits' ray parameters that :func:`render_photons` recorded for these
    heights, replayed instead of searching again (empty: search)."""
    blocks = (stop - start + BLOCK - 1) // BLOCK
    for b in nb.prange(blocks):
        lo = start + b * BLOCK
        vjp_range(d, sc, shifts, indices, lo, min(stop, lo + BLOCK), padded, pad,
                   out[nb.get_thread_id()], hit_t, start)
