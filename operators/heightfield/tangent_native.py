"""The forward pass of the fused height-field kernels: the Jacobian-vector product J v, the change
of the splatted irradiance when the heights move along a direction v (m, m).

Per photon, the same path as a render (:func:`operators.heightfield.kernels_native.trace_packet`),
then three forward steps:

1. the hit: with the Catmull-Rom surface S of d and V of v at the hit (16 samples each),
   dt = V / (w_z - S_x w_x - S_y w_y) (the ray meets the moved surface at another t) and each
   derivative of the jet moves by V's own plus the slide along the ray, dS_x = V_x + (S_xx w_x +
   S_xy w_y) dt and so on: the transpose of :func:`operators.heightfield.intersect_native.hit_adjoint_patch`;
2. the optics: the six splat arguments' changes from the hit's six, row by row of the optics'
   Jacobian, each row one reverse sweep of :func:`operators.heightfield.adjoint_native.optics_adjoint`
   (the same hand-written derivatives the gradient uses, so J and J^T agree by construction);
3. the splat's own derivative (:func:`operators.splat.tangent_native.splat_tangent`).

All arithmetic is float64; the images may be float32. The C kernels have no forward pass yet:
every operator takes these (:meth:`operators.heightfield.trace_native.FusedTracer.jvp`).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from operators.heightfield.adjoint_native import optics_adjoint
from operators.heightfield.catmull_rom import contract, load_patch
from operators.heightfield.intersect_native import surface_derivatives
from operators.heightfield.kernels_native import BLOCK, PACKET, hit_cell, load_hit, optics_state, trace_packet
from operators.kernels.numba_settings import jit_call, jit_inline, jit_parallel
from operators.splat.native import footprint_usable
from operators.splat.tangent_native import splat_tangent

__all__ = ["hit_tangent", "jvp_photons"]


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
    tangent = np.empty(6)  # d (flux, px, py, q00, q01, q11)
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
            for i in range(6):
                row = optics_adjoint(sc, w, dwu, dwv, flux, t, jet, eta, state, 1.0 if i == 0 else 0.0,
                                     1.0 if i == 1 else 0.0, 1.0 if i == 2 else 0.0, 1.0 if i == 3 else 0.0,
                                     1.0 if i == 4 else 0.0, 1.0 if i == 5 else 0.0)
                tangent[i] = (row[0] * dhit[0] + row[1] * dhit[1] + row[2] * dhit[2] + row[3] * dhit[3]
                              + row[4] * dhit[4] + row[5] * dhit[5])
            splat_tangent(img, channel[k], px, py, q00, q01, q11, f, tangent, buf)


@jit_parallel
def jvp_photons(d, v, sc, shifts, indices, start, stop, out, capacity) -> None:
    """Add to ``out`` (threads, c, n, n) the change of the flux per pixel of photons start .. stop-1
    when the heights ``d`` (m, m) move along ``v`` (m, m), both float64 (sum over axis 0 after)."""
    blocks = (stop - start + BLOCK - 1) // BLOCK
    for b in nb.prange(blocks):
        lo = start + b * BLOCK
        jvp_range(d, v, sc, shifts, indices, lo, min(stop, lo + BLOCK), out[nb.get_thread_id()], capacity)
