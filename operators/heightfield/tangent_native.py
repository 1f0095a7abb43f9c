"""The forward pass of the fused height-field kernels: the Jacobian-vector product J v, the change
of the splatted irradiance when the heights move along a direction v (m, m).

Per photon, the same path as a render (:func:`operators.heightfield.kernels_native.trace_packet`),
then three forward steps:

1. the hit: with the Catmull-Rom surface S of d and V of v at the hit (16 samples each),
   dt = V / (w_z - S_x w_x - S_y w_y) (the ray meets the moved surface at another t) and each
   derivative of the jet moves by V's own plus the slide along the ray, dS_x = V_x + (S_xx w_x +
   S_xy w_y) dt and so on: the transpose of :func:`operators.heightfield.intersect_native.hit_adjoint_patch`;
2. the optics: the six splat arguments' changes from the hit's six in one forward sweep
   (:func:`optics_tangent`, from the tangents of :mod:`operators.optics.tangent_native`, which cut
   where the gradient's adjoints cut, so that J and J^T agree);
3. the splat's own derivative (:func:`operators.splat.tangent_native.splat_tangent`).

All arithmetic is float64; the images may be float32. The C kernels have no forward pass yet:
every operator takes these (:meth:`operators.heightfield.trace_native.FusedTracer.jvp`).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from operators.heightfield.catmull_rom import contract, load_patch
from operators.heightfield.intersect_native import surface_derivatives
from operators.heightfield.kernels_native import BLOCK, PACKET, hit_cell, load_hit, optics_state, trace_packet
from operators.kernels.numba_settings import jit_call, jit_inline, jit_parallel
from operators.optics.native import UP, ZERO, fresnel
from operators.optics.tangent_native import (footprint_metric_tangent, fresnel_tangent, height_field_normal_tangent,
                                             normal_differential_tangent, plane_distance_tangent, refract_tangent,
                                             transfer_tangent)
from operators.splat.native import footprint_usable
from operators.splat.tangent_native import splat_tangent

__all__ = ["hit_tangent", "jvp_photons", "optics_tangent"]


@jit_inline
def hit_tangent(wx, wy, patch, vpatch, w):
    """(dt, dS_x, dS_y, dS_xx, dS_xy, dS_yy) at one photon's hit when the heights move along v:
    ``patch`` and ``vpatch`` (4, 4) the samples of d and v around the hit, wx / wy the weight
    tables of order 3 there (:func:`operators.heightfield.kernels_native.hit_cell`), w the ray's direction."""
    sx, sy, sxx, sxy, syy, sxxx, sxxy, sxyy, syyy = surface_derivatives(patch, wx, wy)
    dt = contract(vpatch, wx, 0, wy, 0) / (w[2] - sx * w[0] - sy * w[1])
    return (dt,
            contract(vpatch, wx, 1, wy, 0) + (sxx * w[0] + sxy * w[1]) * dt,
            contract(vpatch, wx, 0, wy, 1) + (sxy * w[0] + syy * w[1]) * dt,
            contract(vpatch, wx, 2, wy, 0) + (sxxx * w[0] + sxxy * w[1]) * dt,
            contract(vpatch, wx, 1, wy, 1) + (sxxy * w[0] + sxyy * w[1]) * dt,
            contract(vpatch, wx, 0, wy, 2) + (sxyy * w[0] + syyy * w[1]) * dt)


@jit_inline
def optics_tangent(sc, w, dwu, dwv, flux0, t, jet, eta, state, dhit):
    """The changes (flux, px, py, q00, q01, q11) of a photon's splat arguments
    (:func:`operators.heightfield.kernels_native.splat_arguments`) when its hit moves by ``dhit``
    (:func:`hit_tangent`), forward through its :func:`operators.heightfield.kernels_native.optics_state`:
    the top's refraction, the face it leaves through (a fixed plane), the receiver."""
    sx, sy, sxx, sxy, syy = jet
    t_d, sx_d, sy_d, sxx_d, sxy_d, syy_d = dhit
    top, below, fu, fv = state
    n1, _, dpu1, dpv1, dnu, dnv, w1, dwu1, dwv1, ci1, ct1 = top
    _, dist2, _, dpu2, dpv2, w2, dwu2, dwv2, ci2, ct2, dist3, _, _, _, n2, fx, fy, _ = below
    n1_d = height_field_normal_tangent(sx, sy, sx_d, sy_d)
    p1_d, dpu1_d, dpv1_d = transfer_tangent(ZERO, ZERO, w, dwu, dwv, t, n1, ZERO, ZERO, ZERO, ZERO, ZERO, ZERO,
                                            t_d, n1_d)
    dnu_d = normal_differential_tangent(sxx, sxy, syy, n1, dpu1, sxx_d, sxy_d, syy_d, n1_d, dpu1_d)
    dnv_d = normal_differential_tangent(sxx, sxy, syy, n1, dpv1, sxx_d, sxy_d, syy_d, n1_d, dpv1_d)
    w1_d, dwu1_d, dwv1_d, ci1_d, ct1_d = refract_tangent(w, dwu, dwv, n1, dnu, dnv, 1.0 / eta, ZERO, ZERO, ZERO,
                                                         n1_d, dnu_d, dnv_d)
    dist2_d = plane_distance_tangent(w1, n2, dist2, p1_d, w1_d)
    p2_d, dpu2_d, dpv2_d = transfer_tangent(dpu1, dpv1, w1, dwu1, dwv1, dist2, n2, p1_d, dpu1_d, dpv1_d, w1_d, dwu1_d,
                                            dwv1_d, dist2_d, ZERO)
    w2_d, dwu2_d, dwv2_d, ci2_d, ct2_d = refract_tangent(w1, dwu1, dwv1, n2, ZERO, ZERO, eta, w1_d, dwu1_d, dwv1_d,
                                                         ZERO, ZERO, ZERO)
    dist3_d = plane_distance_tangent(w2, UP, dist3, p2_d, w2_d)
    p3_d, dpu3_d, dpv3_d = transfer_tangent(dpu2, dpv2, w2, dwu2, dwv2, dist3, UP, p2_d, dpu2_d, dpv2_d, w2_d, dwu2_d,
                                            dwv2_d, dist3_d, ZERO)
    flux_d = 0.0
    if sc.fresnel:
        t1 = fresnel(ci1, ct1, 1.0 / eta)
        t2 = fresnel(ci2, ct2, eta)
        flux_d = flux0 * (fresnel_tangent(ci1, ct1, 1.0 / eta, ci1_d, ct1_d) * t2
                          + t1 * fresnel_tangent(ci2, ct2, eta, ci2_d, ct2_d))
    kx, ky = sc.to_px * fx, sc.to_px * fy  # pixels, the walls' mirror undone
    q00_d, q01_d, q11_d = footprint_metric_tangent(fu[0], fu[1], fv[0], fv[1], sc.min_px, sc.max_px, dpu3_d[0] * kx,
                                                   dpu3_d[1] * ky, dpv3_d[0] * kx, dpv3_d[1] * ky)
    return flux_d, p3_d[0] * kx, p3_d[1] * ky, q00_d, q01_d, q11_d


@jit_call
def jvp_range(d, v, sc, shifts, indices, lo, hi, img, capacity) -> None:
    """One thread's share of :func:`jvp_photons`: photons lo .. hi-1 into its own image ``img``
    (c, n, n), in packets of PACKET as a render traces them."""
    wx = np.empty((4, 4))
    wy = np.empty((4, 4))
    patch = np.empty((4, 4))
    vpatch = np.empty((4, 4))
    hits = np.empty((17, PACKET))  # per photon: w, Dw_u, Dw_v, flux, t, jet, eta
    search = np.empty((5, PACKET))
    channel = np.empty(PACKET, dtype=np.int64)
    spots = np.empty((6, PACKET))  # per photon: px, py, q00, q01, q11, flux
    buf = np.empty((2, capacity))
    no_hits = np.empty(0)
    for first in range(lo, hi, PACKET):
        count = min(PACKET, hi - first)
        trace_packet(d, sc, shifts, indices, first, count, hits, channel, spots, search, no_hits, first, False)
        for k in range(count):
            px, py, q00, q01, q11, f = spots[0, k], spots[1, k], spots[2, k], spots[3, k], spots[4, k], spots[5, k]
            if not footprint_usable(f, px, py, q00, q01, q11):
                continue
            w, dwu, dwv, flux, t, jet, eta = load_hit(hits, k)
            ix, iy = hit_cell(d, sc, w, t, wx, wy, patch)
            load_patch(v, ix, iy, vpatch)
            dhit = hit_tangent(wx, wy, patch, vpatch, w)
            state = optics_state(sc, w, dwu, dwv, t, jet, eta)
            tangent = optics_tangent(sc, w, dwu, dwv, flux, t, jet, eta, state, dhit)
            splat_tangent(img, channel[k], px, py, q00, q01, q11, f, tangent, buf)


@jit_parallel
def jvp_photons(d, v, sc, shifts, indices, start, stop, out, capacity) -> None:
    """Add to ``out`` (threads, c, n, n) the change of the flux per pixel of photons start .. stop-1
    when the heights ``d`` (m, m) move along ``v`` (m, m), both float64 (sum over axis 0 after)."""
    blocks = (stop - start + BLOCK - 1) // BLOCK
    for b in nb.prange(blocks):
        lo = start + b * BLOCK
        jvp_range(d, v, sc, shifts, indices, lo, min(stop, lo + BLOCK), out[nb.get_thread_id()], capacity)
