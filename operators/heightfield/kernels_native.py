"""Fused native photon kernels: emission, trace, footprint and splat (or its adjoint) per photon.

One numba pass per chunk of photons does what :mod:`operators.emission`,
:mod:`operators.heightfield.trace_reference`, :func:`operators.splat.splat.footprint_metric` and
:mod:`operators.splat.native` do with torch tensors, without materialising any per-photon array:
``render_photons`` scatters into per-thread images; the reverse pass, ``vjp_photons``, is in
:mod:`operators.heightfield.adjoint_native`. All arithmetic is float64; only the images may be
float32.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from operators.emission import R2_STEP
from operators.heightfield.catmull_rom import axis_weights, load_patch, surface_jet_at
from operators.heightfield.intersect_native import solve_hit, solve_hits
from operators.heightfield.side_walls import LOST, leaving_plane
from operators.kernels.numba_settings import jit_call, jit_inline, jit_parallel
from operators.kernels.simd import data_pointer, surface_jets
from operators.optics.native import (UP, ZERO, away_from_zero, dot, footprint_metric, fresnel, height_field_normal,
                                     normal_differential, refract, transfer)
from operators.splat.native import splat_photon


class FusedScene(NamedTuple):
    """Scene constants of the fused kernels (floats in scene units unless stated).

    light_*: light position; half: substrate half width (also the height grid's extent);
    base: substrate thickness (z of d = 0); spacing: height-grid spacing; zlo / zhi: planes that
    bracket the surface, zstart: plane where the hit search starts Newton (HeightFieldGrid.z_planes);
    slope_x, slope_y: bounds on the surface's slopes (HeightFieldGrid.slope_bounds);
    per_channel: photons per channel; flux_scale: P / (4 pi c) A_cell (l_z - h), so
    flux = flux_scale / r^3; radius: emission footprint radius on z = h; aim_half: half width
    of the square on z = h the photons aim at (operators/emission.py, ``aim_half_width``);
    receiver_z, receiver_half: receiver plane and half width; to_px: pixels per scene unit;
    min_px, max_px: footprint pixel filter and cut-off radii (pixels); fresnel: Fresnel weights;
    simd: the CPU kernels take the splat, its gather, the jets and the hit adjoint from the AVX2
    extension (:mod:`operators.kernels.simd`; only where it is available); clear_walls: the
    substrate's side walls refract and reflect (else they absorb; :mod:`operators.heightfield.side_walls`).
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
    clear_walls: bool
    aim_half: float


_jit = jit_inline


@_jit
def emit(index, sc, shifts):
    """Photon ``index`` (channel-major) as in LightEmitter.batch: (channel, w, D_u w, D_v w, flux)."""
    c = index // sc.per_channel
    j = float(index - c * sc.per_channel)
    u = shifts[c, 0] + j * R2_STEP[0]
    v = shifts[c, 1] + j * R2_STEP[1]
    u -= math.floor(u)
    v -= math.floor(v)
    dx = (2.0 * sc.aim_half) * u - sc.aim_half - sc.light_x
    dy = (2.0 * sc.aim_half) * v - sc.aim_half - sc.light_y
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
    """From the top hit to the receiver, through the bottom or a side wall
    (:func:`operators.heightfield.side_walls.leaving_plane`): (lost, dist2, p2, Dp2, w2, Dw2,
    cos_i, cos_t, dist3, p3, Dp3, n2, fx, fy, code), with p3 and Dp3 mirrored by the walls'
    total reflections (x -> fx x + ox, y likewise) and n2 the face the photon leaves through."""
    n2, c2, fx, ox, fy, oy, walled, code = leaving_plane(p1, w1, eta, sc.half, sc.clear_walls)
    dist2 = (c2 - dot(p1, n2)) / away_from_zero(dot(w1, n2))
    p2, dpu2, dpv2 = transfer(p1, dpu1, dpv1, w1, dwu1, dwv1, dist2, n2)
    w2, dwu2, dwv2, ci2, ct2, k2 = refract(w1, dwu1, dwv1, n2, ZERO, ZERO, eta)
    lost = walled or k2 <= 0.0
    dist3 = (sc.receiver_z - p2[2]) / away_from_zero(w2[2])
    p3, dpu3, dpv3 = transfer(p2, dpu2, dpv2, w2, dwu2, dwv2, dist3, UP)
    p3 = (fx * p3[0] + ox, fy * p3[1] + oy, p3[2])
    dpu3 = (fx * dpu3[0], fy * dpu3[1], dpu3[2])
    dpv3 = (fx * dpv3[0], fy * dpv3[1], dpv3[2])
    return (lost, dist2, p2, dpu2, dpv2, w2, dwu2, dwv2, ci2, ct2, dist3, p3, dpu3, dpv3, n2, fx, fy,
            LOST if lost else code)


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
def load_hit(hits, k):
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
    (w, Dw_u, Dw_v, flux, t, jet, eta; :func:`load_hit`), channels in ``channel`` and splat
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
        w, dwu, dwv, flux, t_k, jet, eta = load_hit(hits, k)
        spot = splat_arguments(sc, flux, eta, optics_state(sc, w, dwu, dwv, t_k, jet, eta))
        for j in range(6):
            spots[j, k] = spot[j]


@jit_call
def render_range(d, sc, shifts, indices, lo, hi, img, capacity, splat, hit_t, t_first, replay=False) -> float:
    """One thread's share of :func:`render_photons`: photons lo .. hi-1 into its own image ``img``
    (c, n, n), their hits recorded in ``hit_t`` unless it is empty (with ``replay``: read from it
    instead of searched); returns the flux that reached the receiver."""
    buf = np.empty(capacity)
    hits = np.empty((17, PACKET))  # per photon: w, Dw_u, Dw_v, flux, t, jet, eta
    search = np.empty((5, PACKET))  # the hit search's brackets, state, gaps and slopes
    channel = np.empty(PACKET, dtype=np.int64)
    spots = np.empty((6, PACKET))  # per photon: px, py, q00, q01, q11, flux
    reached = 0.0
    for first in range(lo, hi, PACKET):
        count = min(PACKET, hi - first)
        trace_packet(d, sc, shifts, indices, first, count, hits, channel, spots, search, hit_t, t_first, replay)
        for k in range(count):
            reached += spots[5, k]
            if splat:
                splat_photon(img, channel[k], spots[0, k], spots[1, k], spots[2, k], spots[3, k], spots[4, k],
                             spots[5, k], buf, sc.simd)
    return reached


# Photons per block; the host hands blocks to the threads one at a time (parallel_chunksize(1)),
# which balances threads that share a core with other work.
BLOCK = 4096


@jit_parallel
def render_photons(d, sc, shifts, indices, start, stop, out, capacity, splat, hit_t, replay=False):
    """Splat photons start .. stop-1 into ``out`` (threads, c, n, n) (flux per pixel, sum over
    axis 0 after). ``d`` (m, m) float64 heights, ``shifts`` (c, 2) emission offsets, ``indices``
    (c,) refractive indices, ``capacity`` the pixels of the largest footprint. With ``splat``
    False only the traces run (for timing). ``hit_t`` (stop - start,) receives the hits' ray
    parameters, for :func:`vjp_photons` to replay (empty: not recorded); with ``replay`` it holds
    them already (recorded for these heights and this light) and the hit search is skipped.
    Returns the total flux that reached the receiver."""
    blocks = (stop - start + BLOCK - 1) // BLOCK
    reached = np.zeros(blocks)
    for b in nb.prange(blocks):
        lo = start + b * BLOCK
        reached[b] = render_range(d, sc, shifts, indices, lo, min(stop, lo + BLOCK), out[nb.get_thread_id()],
                                   capacity, splat, hit_t, start, replay)
    return reached.sum()
