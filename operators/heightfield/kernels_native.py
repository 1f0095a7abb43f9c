"""Fused native photon kernels: emission, trace, footprint and splat (or its adjoint) per photon.

One numba pass per chunk of photons does what :mod:`operators.emission`,
:mod:`operators.heightfield.trace_reference`, :func:`operators.splat.splat.footprint_metric` and
:mod:`operators.splat.native` do with torch tensors, without materialising any per-photon array:
``render_photons`` scatters into per-thread images, ``vjp_photons`` recomputes each photon's path,
gathers the splat adjoint, back-propagates it through the optics (hand-written reverse mode,
:mod:`operators.optics.native`) to the hit's ray parameter and surface jet, and from there into the
16 Catmull-Rom control heights (:func:`operators.heightfield.intersect_native.hit_adjoint_patch`),
accumulating per-thread gradients. All arithmetic is float64; only the images may be float32.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from operators.heightfield.catmull_rom import axis_weights, load_patch, scatter_patch, surface_jet_at
from operators.emission import R2_STEP
from operators.heightfield.intersect_native import hit_adjoint_patch, solve_hit, solve_hits
from operators.kernels.numba_settings import FAST_MATH
from operators.optics.native import (UP, ZERO, add, away_from_zero, footprint_metric, footprint_metric_adjoint,
                                     fresnel, fresnel_adjoint, height_field_normal, height_field_normal_adjoint,
                                     normal_differential, normal_differential_adjoint, passes, refract,
                                     refract_adjoint, transfer, transfer_adjoint)
from operators.kernels.simd import data_pointer, hit_adjoint, surface_jets
from operators.splat.native import gather_photon, gather_photon_simd, splat_photon


class FusedScene(NamedTuple):
    """Scene constants of the fused kernels (floats in scene units unless stated).

    light_*: light position; half: substrate half width (also the height grid's extent);
    base: substrate thickness (z of d = 0); spacing: height-grid spacing; zlo / zhi: planes that
    bracket the surface, zstart: plane where the hit search starts Newton (HeightFieldGrid.z_planes);
    slope_x, slope_y: bounds on the surface's slopes (HeightFieldGrid.slope_bounds);
    per_channel: photons per channel; flux_scale: P / (4 pi c) A_cell (l_z - h), so
    flux = flux_scale / r^3; radius: emission footprint radius on z = h;
    receiver_z, receiver_half: receiver plane and half width; to_px: pixels per scene unit;
    min_px, max_px: footprint pixel filter and cut-off radii (pixels); fresnel: Fresnel weights;
    simd: the CPU kernels take the splat, its gather, the jets and the hit adjoint from the AVX2
    extension (:mod:`operators.kernels.simd`; only where it is available).
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
    simd: bool


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
def jet_at(d, sc, w, t):
    """Surface jet (S_x, S_y, S_xx, S_xy, S_yy) where the photon along w meets the surface at t."""
    return surface_jet_at(d, sc.light_x + t * w[0], sc.light_y + t * w[1], -sc.half, sc.spacing)


@_jit
def packet_jets(d, sc, dirs, t, count, jets) -> None:
    """Surface jets (:func:`jet_at`) of rays k < count along dirs[0:3, k] at t[k] into
    jets[0:5, k]; dirs and jets with the same row stride, rows unit-stride (AVX2 with sc.simd)."""
    if sc.simd:
        surface_jets(data_pointer(d), d.shape[0], -sc.half, 1.0 / sc.spacing, sc.light_x, sc.light_y,
                     data_pointer(dirs), dirs.strides[0] // 8, data_pointer(t), count, data_pointer(jets))
        return
    for k in range(count):
        jets[0, k], jets[1, k], jets[2, k], jets[3, k], jets[4, k] = jet_at(d, sc, (dirs[0, k], dirs[1, k], dirs[2, k]),
                                                                            t[k])


@_jit
def hit_jet(d, sc, w):
    """Ray parameter t of the first hit on the printed surface and the jet there, (t, jet)."""
    t = solve_hit(d, sc.base, sc.light_x, sc.light_y, sc.light_z, w[0], w[1], w[2], -sc.half, sc.spacing, sc.zlo,
                  sc.zstart, sc.zhi, sc.slope_x, sc.slope_y)
    return t, jet_at(d, sc, w, t)


@_jit
def hit_cell(d, sc, w, t, wx, wy, patch):
    """Load the weight tables of order 3 (wx, wy) and the 16 samples (patch) of the cell where
    the ray along w meets the surface at t; returns the cell (ix, iy)."""
    m = d.shape[0]
    ix = axis_weights(sc.light_x + t * w[0], -sc.half, sc.spacing, m, 3, wx)
    iy = axis_weights(sc.light_y + t * w[1], -sc.half, sc.spacing, m, 3, wy)
    load_patch(d, ix, iy, patch)
    return ix, iy


@_jit
def refract_top(sc, w, dwu, dwv, t, jet, eta):
    """Photon along w (differentials Dw) from the light, refracted into the glass at its hit t
    (surface jet there): (n, p1, Dp1, Dn, w1, Dw1, cos_i, cos_t), each D a u, v pair."""
    sx, sy, sxx, sxy, syy = jet
    n1 = height_field_normal(sx, sy)
    p1, dpu1, dpv1 = transfer((sc.light_x, sc.light_y, sc.light_z), ZERO, ZERO, w, dwu, dwv, t, n1)
    dnu = normal_differential(sxx, sxy, syy, n1, dpu1)
    dnv = normal_differential(sxx, sxy, syy, n1, dpv1)
    w1, dwu1, dwv1, ci1, ct1, _ = refract(w, dwu, dwv, n1, dnu, dnv, 1.0 / eta)
    return n1, p1, dpu1, dpv1, dnu, dnv, w1, dwu1, dwv1, ci1, ct1


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
def optics_state(sc, w, dwu, dwv, t, jet, eta):
    """Every intermediate of a photon's optics from its hit at t to the receiver that the adjoint
    needs: (top, below, Du, Dv) with top = :func:`refract_top`, below = :func:`below_top`, and
    Du, Dv the receiver footprint vectors in pixels."""
    top = refract_top(sc, w, dwu, dwv, t, jet, eta)
    _, p1, dpu1, dpv1, _, _, w1, dwu1, dwv1, _, _ = top
    below = below_top(p1, dpu1, dpv1, w1, dwu1, dwv1, eta, sc)
    dpu3, dpv3 = below[12], below[13]
    k = sc.to_px
    return top, below, (dpu3[0] * k, dpu3[1] * k), (dpv3[0] * k, dpv3[1] * k)


@_jit
def splat_arguments(sc, flux, eta, state):
    """(px, py, q00, q01, q11, flux) of a photon on the receiver from its :func:`optics_state`
    (flux with the Fresnel weights if on; 0 if lost)."""
    top, below, fu, fv = state
    ci1, ct1 = top[9], top[10]
    lost, ci2, ct2, p3 = below[0], below[8], below[9], below[11]
    if sc.fresnel:
        flux *= fresnel(ci1, ct1, 1.0 / eta) * fresnel(ci2, ct2, eta)
    q00, q01, q11 = footprint_metric(fu[0], fu[1], fv[0], fv[1], sc.min_px, sc.max_px)
    if lost:
        return 0.0, 0.0, 1.0, 0.0, 1.0, 0.0
    k = sc.to_px
    return (p3[0] + sc.receiver_half) * k - 0.5, (p3[1] + sc.receiver_half) * k - 0.5, q00, q01, q11, flux


@_jit
def trace_photon(d, sc, shifts, indices, index):
    """Photon ``index`` on the receiver: (channel, px, py, q00, q01, q11, flux) in pixels; flux 0 if lost."""
    c, w, dwu, dwv, flux = emit(index, sc, shifts)
    t, jet = hit_jet(d, sc, w)
    eta = indices[c]
    px, py, q00, q01, q11, flux = splat_arguments(sc, flux, eta, optics_state(sc, w, dwu, dwv, t, jet, eta))
    return c, px, py, q00, q01, q11, flux


@_jit
def _store_emission(hits, k, w, dwu, dwv, flux, eta) -> None:
    """Column k of a packet's hit table (17, PACKET) but the hit: w, Dw_u, Dw_v, flux and eta
    (rows 10 .. 15, t and the jet, follow once the hit is found)."""
    hits[0, k], hits[1, k], hits[2, k] = w
    hits[3, k], hits[4, k], hits[5, k] = dwu
    hits[6, k], hits[7, k], hits[8, k] = dwv
    hits[9, k] = flux
    hits[16, k] = eta


@_jit
def _load_hit(hits, k):
    """(w, Dw_u, Dw_v, flux, t, jet, eta) from column k of a packet's hit table."""
    return ((hits[0, k], hits[1, k], hits[2, k]), (hits[3, k], hits[4, k], hits[5, k]),
            (hits[6, k], hits[7, k], hits[8, k]), hits[9, k], hits[10, k],
            (hits[11, k], hits[12, k], hits[13, k], hits[14, k], hits[15, k]), hits[16, k])


# Photons traced together by one thread: the hit searches of the packet in lockstep, then the
# optics of the whole packet as one loop that LLVM vectorises (SIMD across photons), then the splats.
PACKET = 128


@_jit
def trace_packet(d, sc, shifts, indices, first, count, hits, channel, spots, search, hit_t, t_first, replay) -> None:
    """Photons first .. first+count-1 traced to the receiver: their hits in ``hits`` (17, PACKET)
    (w, Dw_u, Dw_v, flux, t, jet, eta; :func:`_load_hit`), channels in ``channel`` and splat
    arguments (px, py, q00, q01, q11, flux) in ``spots`` (6, PACKET); ``search`` (5, PACKET) is
    the hit search's scratch. The hit searches run in lockstep over the packet
    (:func:`operators.heightfield.intersect_native.solve_hits`), the optics as one loop over the packet
    that LLVM vectorises.

    ``hit_t`` holds the hits' ray parameters of photons t_first, t_first + 1, ... (a hit cache,
    :class:`operators.heightfield.trace_native.HitCache`): with ``replay`` they are read from it instead of
    searched for; otherwise, unless it is empty, the searched ones are written into it."""
    for k in range(count):
        c, w, dwu, dwv, flux = emit(first + k, sc, shifts)
        channel[k] = c
        _store_emission(hits, k, w, dwu, dwv, flux, indices[c])
    t = hits[10]
    offset = first - t_first
    if replay:
        for k in range(count):
            t[k] = hit_t[offset + k]
    else:
        solve_hits(d, sc.base, sc.light_x, sc.light_y, sc.light_z, hits, count, -sc.half, sc.spacing, sc.zlo,
                   sc.zstart, sc.zhi, sc.slope_x, sc.slope_y, t, search)
        if hit_t.shape[0] > 0:
            for k in range(count):
                hit_t[offset + k] = t[k]
    packet_jets(d, sc, hits, t, count, hits[11:16])
    for k in range(count):
        w, dwu, dwv, flux, t_k, jet, eta = _load_hit(hits, k)
        spot = splat_arguments(sc, flux, eta, optics_state(sc, w, dwu, dwv, t_k, jet, eta))
        for j in range(6):
            spots[j, k] = spot[j]


@nb.njit(cache=True, fastmath=FAST_MATH, error_model="numpy")
def render_range(d, sc, shifts, indices, lo, hi, img, capacity, splat, hit_t, t_first) -> float:
    """One thread's share of :func:`render_photons`: photons lo .. hi-1 into its own image ``img``
    (c, n, n), their hits recorded in ``hit_t`` unless it is empty; returns the flux that reached
    the receiver."""
    buf = np.empty(capacity)
    hits = np.empty((17, PACKET))  # per photon: w, Dw_u, Dw_v, flux, t, jet, eta
    search = np.empty((5, PACKET))  # the hit search's brackets, state, gaps and slopes
    channel = np.empty(PACKET, dtype=np.int64)
    spots = np.empty((6, PACKET))  # per photon: px, py, q00, q01, q11, flux
    reached = 0.0
    for first in range(lo, hi, PACKET):
        count = min(PACKET, hi - first)
        trace_packet(d, sc, shifts, indices, first, count, hits, channel, spots, search, hit_t, t_first, False)
        for k in range(count):
            reached += spots[5, k]
            if splat:
                splat_photon(img, channel[k], spots[0, k], spots[1, k], spots[2, k], spots[3, k], spots[4, k],
                             spots[5, k], buf, sc.simd)
    return reached


# Photons per block; the host hands blocks to the threads one at a time (parallel_chunksize(1)),
# which balances threads that share a core with other work.
BLOCK = 4096


@nb.njit(parallel=True, cache=True, fastmath=FAST_MATH, error_model="numpy")
def render_photons(d, sc, shifts, indices, start, stop, out, capacity, splat, hit_t):
    """Splat photons start .. stop-1 into ``out`` (threads, c, n, n) (flux per pixel, sum over
    axis 0 after). ``d`` (m, m) float64 heights, ``shifts`` (c, 2) emission offsets, ``indices``
    (c,) refractive indices, ``capacity`` the pixels of the largest footprint. With ``splat``
    False only the traces run (for timing). ``hit_t`` (stop - start,) receives the hits' ray
    parameters, for :func:`vjp_photons` to replay (empty: not recorded). Returns the total flux
    that reached the receiver."""
    blocks = (stop - start + BLOCK - 1) // BLOCK
    reached = np.zeros(blocks)
    for b in nb.prange(blocks):
        lo = start + b * BLOCK
        reached[b] = render_range(d, sc, shifts, indices, lo, min(stop, lo + BLOCK), out[nb.get_thread_id()],
                                   capacity, splat, hit_t, start)
    return reached.sum()


@_jit
def optics_adjoint(sc, w, dwu, dwv, flux0, t, jet, eta, state, g_flux, g_px, g_py, g00, g01, g11):
    """Reverse mode through the optics: gradients of a loss with the given gradients w.r.t. the
    splat arguments (:func:`splat_arguments`) back to the hit, (g_t, g_sx, g_sy, g_sxx, g_sxy, g_syy)."""
    sx, sy, sxx, sxy, syy = jet
    top, below, fu, fv = state
    n1, p1, dpu1, dpv1, dnu, dnv, w1, dwu1, dwv1, ci1, ct1 = top
    _, dist2, p2, dpu2, dpv2, w2, dwu2, dwv2, ci2, ct2, dist3, p3, dpu3, dpv3 = below
    t1 = fresnel(ci1, ct1, 1.0 / eta) if sc.fresnel else 1.0
    t2 = fresnel(ci2, ct2, eta) if sc.fresnel else 1.0
    k = sc.to_px
    g_ux, g_uy, g_vx, g_vy = footprint_metric_adjoint(fu[0], fu[1], fv[0], fv[1], sc.min_px, sc.max_px,
                                                      g00, g01, g11)
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
    return g_t, g_sx, g_sy, g_sxx + g_sxx2, g_sxy + g_sxy2, g_syy + g_syy2


@_jit
def _contributes(g) -> bool:
    """Whether a photon's splat-adjoint gradients (:func:`gather_photon`) are not all zero."""
    return not (g[0] == 0.0 and g[1] == 0.0 and g[2] == 0.0 and g[3] == 0.0 and g[4] == 0.0 and g[5] == 0.0)


@_jit
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


@nb.njit(cache=True, fastmath=FAST_MATH, error_model="numpy")
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
            w, dwu, dwv, flux, t, jet, eta = _load_hit(hits, k)
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


@nb.njit(parallel=True, cache=True, fastmath=FAST_MATH, error_model="numpy")
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
