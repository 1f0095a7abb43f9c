"""The reverse kernel of the mesh-scene operator (:mod:`operators.mesh.kernels_native`): ``retreat``
takes an event's inputs (the state before it, the event's kind, face and distance) and the
gradient w.r.t. the state after it, and returns the gradient w.r.t. the state before it; at the
printed top it adds the gradient w.r.t. the heights into a per-thread array instead (the state
before a photon's first top hit does not depend on the heights).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from operators.heightfield.catmull_rom import axis_weights, load_patch, scatter_patch
from operators.heightfield.intersect_native import hit_adjoint_patch
from operators.kernels.numba_settings import jit_call, jit_parallel
from operators.mesh.kernels_native import (AT_TOP, BLOCK, DPU, DPV, DWU, DWV, ESCAPED, FLUX, INSIDE_TOP, LANDED, MESH,
                                           RECEIVER, STATE, TOP, P, W, event_surface, face_shading, interface, put, vec)
from operators.optics.native import (ZERO, add, axpy, dot, footprint_metric_adjoint, fresnel, fresnel_adjoint,
                                     height_field_normal_adjoint, normal_differential_adjoint, refract_adjoint, scale,
                                     transfer_adjoint)

__all__ = ["retreat", "splat_arguments_adjoint"]


@jit_call
def _shading_differential_adjoint(normal, length, e1, e2, g1, g2, dp, dn, g_dn):
    """Adjoint of :func:`shading_differential`: (g_normal, g_length, g_dp)."""
    m = axpy(dot(g1, dp), e1, scale(dot(g2, dp), e2))
    s = dot(normal, m)
    ng = dot(normal, g_dn)
    g_m = scale(1.0 / length, axpy(-ng, normal, g_dn))
    g_normal = scale(-1.0 / length, axpy(s, g_dn, scale(ng, m)))
    g_length = -dot(dn, g_dn) / length
    return g_normal, g_length, axpy(dot(e1, g_m), g1, scale(dot(e2, g_m), g2))


@jit_call
def _reflect_adjoint(w, dwu, dwv, n, dnu, dnv, g_r, g_ru, g_rv):
    """Adjoint of :func:`reflect`: (g_w, g_dwu, g_dwv, g_n, g_dnu, g_dnv)."""
    c = dot(w, n)
    cu = dot(dwu, n) + dot(w, dnu)
    cv = dot(dwv, n) + dot(w, dnv)
    g_cu = -2.0 * dot(g_ru, n)
    g_cv = -2.0 * dot(g_rv, n)
    g_c = -2.0 * (dot(g_r, n) + dot(g_ru, dnu) + dot(g_rv, dnv))
    g_w = axpy(g_c, n, axpy(g_cu, dnu, axpy(g_cv, dnv, g_r)))
    g_n = axpy(
        -2.0 * c, g_r, axpy(-2.0 * cu, g_ru, axpy(-2.0 * cv, g_rv, axpy(g_c, w, axpy(g_cu, dwu, scale(g_cv, dwv)))))
    )
    return (g_w, axpy(g_cu, n, g_ru), axpy(g_cv, n, g_rv), g_n, axpy(g_cu, w, scale(-2.0 * c, g_ru)),
            axpy(g_cv, w, scale(-2.0 * c, g_rv)))


@jit_call
def _retreat_one(d, i, before, kind, which, t, channel, substrate, face_element, indices, v0, plane, dual, shading, sc,
                 g_after, g_heights, wx, wy, patch) -> None:
    """Reverse of photon i's event (see :func:`retreat`); wx, wy, patch: (4, 4) scratch."""
    k = kind[i]
    row, g = before[i], g_after[i]
    p, dpu, dpv = vec(row, P), vec(row, DPU), vec(row, DPV)
    w, dwu, dwv = vec(row, W), vec(row, DWU), vec(row, DWV)
    n_plane, outward, dnu, dnv, jet, q, dqu, dqv = event_surface(d, row, k, which[i], t[i], shading, dual, plane, v0,
                                                            sc)
    g_q, g_dqu, g_dqv = vec(g, P), vec(g, DPU), vec(g, DPV)
    g_w, g_dwu, g_dwv, g_flux = ZERO, ZERO, ZERO, g[FLUX]
    if k != RECEIVER:
        solid = face_element[which[i]] if k == MESH else substrate
        entering, sign, eta, r, ru, rv, ci, ct, through = interface(
            w, dwu, dwv, n_plane, outward, dnu, dnv, indices[solid, channel[i]])
        facing, dfu, dfv = scale(sign, outward), scale(sign, dnu), scale(sign, dnv)
        g_r, g_ru, g_rv = vec(g, W), vec(g, DWU), vec(g, DWV)
        if through:
            g_ci = g_ct = 0.0
            if sc.fresnel:
                kept = fresnel(ci, ct, eta)
                g_ci, g_ct = fresnel_adjoint(ci, ct, eta, g[FLUX] * row[FLUX])
                g_flux = g[FLUX] * kept
            g_w, g_dwu, g_dwv, g_f, g_fu, g_fv = refract_adjoint(w, dwu, dwv, facing, dfu, dfv, eta, g_r, g_ru,
                                                                 g_rv, g_ci, g_ct)
        else:
            g_w, g_dwu, g_dwv, g_f, g_fu, g_fv = _reflect_adjoint(w, dwu, dwv, facing, dfu, dfv, g_r, g_ru, g_rv)
        g_out, g_dnu, g_dnv = scale(sign, g_f), scale(sign, g_fu), scale(sign, g_fv)
        if k == MESH:
            normal, length, e1, e2, g1, g2 = face_shading(q, which[i], v0, dual, shading)
            gn_u, gl_u, gp_u = _shading_differential_adjoint(normal, length, e1, e2, g1, g2, dqu, dnu, g_dnu)
            gn_v, gl_v, gp_v = _shading_differential_adjoint(normal, length, e1, e2, g1, g2, dqv, dnv, g_dnv)
            g_dqu, g_dqv = add(g_dqu, gp_u), add(g_dqv, gp_v)
            g_normal = add(g_out, add(gn_u, gn_v))
            # N = raw / |raw|, raw = n0 + b1 e1 + b2 e2, b_k = g_k . (q - v0).
            g_raw = axpy(gl_u + gl_v - dot(normal, g_normal) / length, normal, scale(1.0 / length, g_normal))
            g_q = axpy(dot(e1, g_raw), g1, axpy(dot(e2, g_raw), g2, g_q))
        elif k == TOP:
            g_sxx, g_sxy, g_syy, g_nu, g_dpu = normal_differential_adjoint(jet[2], jet[3], jet[4], n_plane, dqu,
                                                                           g_dnu)
            g_sxx2, g_sxy2, g_syy2, g_nv, g_dpv = normal_differential_adjoint(jet[2], jet[3], jet[4], n_plane,
                                                                              dqv, g_dnv)
            g_dqu, g_dqv = add(g_dqu, g_dpu), add(g_dqv, g_dpv)
            g_n_plane = add(g_out, add(g_nu, g_nv))
            _, _, _, _, _, g_t, g_nt = transfer_adjoint(dpu, dpv, w, dwu, dwv, t[i], n_plane, g_q, g_dqu, g_dqv)
            g_sx, g_sy = height_field_normal_adjoint(jet[0], jet[1], add(g_n_plane, g_nt))
            _top_adjoint(d, p, w, t[i], g_t, g_sx, g_sy, g_sxx + g_sxx2, g_sxy + g_sxy2, g_syy + g_syy2, sc,
                         g_heights, wx, wy, patch)
            for j in range(STATE):
                g[j] = 0.0
            return
    g_dpu, g_dpv, g_wt, g_dwut, g_dwvt, g_t, _ = transfer_adjoint(dpu, dpv, w, dwu, dwv, t[i], n_plane, g_q,
                                                                 g_dqu, g_dqv)
    # The distance to a fixed plane: t = (c - p . n) / (w . n).
    wn = dot(w, n_plane)
    g_p = axpy(-g_t / wn, n_plane, g_q)
    g_w = add(add(g_w, g_wt), scale(-g_t * t[i] / wn, n_plane))
    put(g, P, g_p)
    put(g, DPU, g_dpu)
    put(g, DPV, g_dpv)
    put(g, W, g_w)
    put(g, DWU, add(g_dwu, g_dwut))
    put(g, DWV, add(g_dwv, g_dwvt))
    g[FLUX] = g_flux


@jit_parallel
def retreat(d, before, kind, which, t, channel, substrate, face_element, indices, v0, plane, dual, shading, sc,
            g_after, g_heights) -> None:
    """Reverse of one :func:`advance` event (in place): ``g_after`` (N, STATE), the gradient
    w.r.t. the state after it, becomes the gradient w.r.t. the state before it (``before``). On
    the printed top it goes into the heights instead: ``g_heights`` (threads, m, m), summed after.
    Photons with kind < 0 (not under way in that event) keep their gradient."""
    blocks = (before.shape[0] + BLOCK - 1) // BLOCK
    for b in nb.prange(blocks):
        _retreat_block(b * BLOCK, min(before.shape[0], (b + 1) * BLOCK), d, before, kind, which, t, channel, substrate,
                       face_element, indices, v0, plane, dual, shading, sc, g_after, g_heights[nb.get_thread_id()])


@jit_call
def _retreat_block(lo, hi, d, before, kind, which, t, channel, substrate, face_element, indices, v0, plane, dual,
                   shading, sc, g_after, g_heights) -> None:
    """:func:`retreat` for photons lo .. hi-1 (one thread, its own height gradient)."""
    wx, wy, patch = np.empty((4, 4)), np.empty((4, 4)), np.empty((4, 4))
    for i in range(lo, hi):
        k = kind[i]
        if k < 0 or k == ESCAPED or k == INSIDE_TOP or k == AT_TOP:
            continue
        _retreat_one(d, i, before, kind, which, t, channel, substrate, face_element, indices, v0, plane, dual, shading,
                     sc, g_after, g_heights, wx, wy, patch)


@jit_call
def _top_adjoint(d, p, w, t, g_t, g_sx, g_sy, g_sxx, g_sxy, g_syy, sc, grad, wx, wy, patch) -> None:
    """Add to grad (m, m) the gradient w.r.t. the heights of g_t t + <g_jet, jet> at a hit on the
    top; wx, wy, patch: (4, 4) scratch."""
    m = d.shape[0]
    ix = axis_weights(p[0] + t * w[0], -sc.half, sc.spacing, m, 3, wx)
    iy = axis_weights(p[1] + t * w[1], -sc.half, sc.spacing, m, 3, wy)
    load_patch(d, ix, iy, patch)
    hit_adjoint_patch(wx, wy, patch, w[0], w[1], w[2], g_t, g_sx, g_sy, g_sxx, g_sxy, g_syy)
    scatter_patch(grad, ix, iy, patch)


@jit_parallel
def splat_arguments_adjoint(state, status, sc, g_pos, g_metric, g_flux, g_state) -> None:
    """Gradient w.r.t. the photons' states (N, STATE) from those w.r.t. their splat arguments."""
    k = sc.to_px
    for i in nb.prange(state.shape[0]):
        for j in range(STATE):
            g_state[i, j] = 0.0
        if status[i] != LANDED:
            continue
        row = state[i]
        g_ux, g_uy, g_vx, g_vy = footprint_metric_adjoint(row[DPU] * k, row[DPU + 1] * k, row[DPV] * k,
                                                          row[DPV + 1] * k, sc.min_px, sc.max_px, g_metric[0, i],
                                                          g_metric[1, i], g_metric[2, i])
        g_state[i, P], g_state[i, P + 1] = g_pos[0, i] * k, g_pos[1, i] * k
        g_state[i, DPU], g_state[i, DPU + 1] = g_ux * k, g_uy * k
        g_state[i, DPV], g_state[i, DPV + 1] = g_vx * k, g_vy * k
        g_state[i, FLUX] = g_flux[i]
