"""Native kernels of the mesh-scene operator: one event of every photon under way, forward and
reverse, as numba loops over photons.

A photon's state is a row of ``state`` (N, STATE): position p, its differentials D_u p, D_v p,
direction w, its differentials D_u w, D_v w (each 3 floats) and the flux. An event moves a photon
to the nearest of: the face of an element that Embree finds for it (:mod:`operators.mesh.embree_native`,
on the kernel's own thread; the exact hit on
that face's plane, moved to the neighbouring face where Embree's float32 choice lies just beside
it), the printed top (from above), the
substrate's walls and bottom, the receiver plane, or the printed top from inside the glass (a
path not followed: lost). At an interface it refracts with its differentials (the interpolated
shading normal of a face and its derivative along the face; the exact height-field normal and its
derivative on the top) or, under total internal reflection, reflects; with Fresnel weighting the
transmitted share is kept. The maths is :mod:`operators.mesh.operator`'s torch tracer, one
photon at a time with the scalar optics of :mod:`operators.optics.native`.

The reverse kernel, ``retreat``, is in :mod:`operators.mesh.adjoint_native`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb

from operators.heightfield.catmull_rom import surface_jet_at
from operators.heightfield.intersect_native import solve_hit
from operators.kernels.numba_settings import jit_call, jit_inline, jit_parallel
from operators.mesh.culling import CLEAR_COS
from operators.mesh.embree_native import first_face, ray_buffer
from operators.mesh.intersect_reference import MIN_FACE_DISTANCE, START_OFFSET
from operators.optics.native import (UP, ZERO, axpy, dot, footprint_metric, fresnel, height_field_normal,
                                     normal_differential, refract, scale, transfer)

# Row layout of a photon's state.
P, DPU, DPV, W, DWU, DWV, FLUX = 0, 3, 6, 9, 12, 15, 18
STATE = 19
# Event kinds (``kind``), then what ends a photon (``status``).
MESH, TOP, BOX, RECEIVER, ESCAPED, INSIDE_TOP, AT_TOP = 0, 1, 2, 3, 4, 5, 6
UNDER_WAY, LANDED, LOST, WAITING = 0, 1, 2, 3
AIR = -1
# Photons per block of a thread's work.
BLOCK = 4096
# Moves of a hit to the neighbouring face (as operators.mesh.intersect_reference.REFINEMENTS).
REFINEMENTS = 2
# The substrate's walls and bottom: (axis, coordinate sign, outward sign); plane k is at
# coordinate sign * half (walls) or z = 0 (bottom).
BOX_PLANES = ((0, 1.0, 1.0), (0, -1.0, -1.0), (1, 1.0, 1.0), (1, -1.0, -1.0), (2, 0.0, -1.0))


class MeshConstants(NamedTuple):
    """Scene constants of the kernels (scene units): substrate half width and thickness; the
    height grid (spacing, and the bracketing planes and slope bounds of the hit search,
    :class:`operators.heightfield.surface.HeightFieldGrid`); top_max, a plane above the print;
    lowest, the lowest z of any element; the receiver plane; Fresnel weighting; the receiver's
    pixels per unit, half width and footprint radii (pixels) of the splat arguments."""

    half: float
    thickness: float
    spacing: float
    zlo: float
    zstart: float
    zhi: float
    slope_x: float
    slope_y: float
    top_max: float
    lowest: float
    receiver_z: float
    fresnel: bool
    to_px: float
    receiver_half: float
    min_px: float
    max_px: float


_jit = jit_inline
_call = jit_call
_kernel = jit_parallel


@_jit
def vec(a, k):
    return (a[k], a[k + 1], a[k + 2])


@_jit
def _row3(a, f):
    return (a[f, 0], a[f, 1], a[f, 2])


@_jit
def put(a, k, v) -> None:
    a[k], a[k + 1], a[k + 2] = v[0], v[1], v[2]


@_jit
def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@_jit
def _face_hit(p, w, f, v0, plane, dual, neighbour):
    """Exact hit of the ray p + t w on face f's plane, moved across an edge (at most REFINEMENTS
    times) where it lies outside the face: (face, t, b1, b2); t = inf on a plane parallel to w."""
    t, b1, b2 = math.inf, 0.0, 0.0
    for i in range(REFINEMENTS + 1):
        n = _row3(plane, f)
        cos = dot(w, n)
        if abs(cos) <= 1e-12:
            return f, math.inf, 0.0, 0.0
        t = dot(_sub(_row3(v0, f), p), n) / cos
        rel = _sub(axpy(t, w, p), _row3(v0, f))
        b1 = dot(rel, (dual[f, 0, 0], dual[f, 0, 1], dual[f, 0, 2]))
        b2 = dot(rel, (dual[f, 1, 0], dual[f, 1, 1], dual[f, 1, 2]))
        lowest, k = 1.0 - b1 - b2, 0
        if b1 < lowest:
            lowest, k = b1, 1
        if b2 < lowest:
            lowest, k = b2, 2
        across = neighbour[f, k]
        if i == REFINEMENTS or not (lowest < 0.0 and across >= 0):
            break
        f = across
    return f, t, b1, b2


@_jit
def face_shading(q, f, v0, dual, shading):
    """:func:`_shading` of face f at the point q on its plane."""
    rel = _sub(q, _row3(v0, f))
    return _shading(f, dot(rel, (dual[f, 0, 0], dual[f, 0, 1], dual[f, 0, 2])),
                    dot(rel, (dual[f, 1, 0], dual[f, 1, 1], dual[f, 1, 2])), shading, dual)


@_jit
def _shading(f, b1, b2, shading, dual):
    """Interpolated shading normal on face f at barycentrics (b1, b2): (N, |raw|, e1, e2, g1, g2)
    with raw = n0 + b1 e1 + b2 e2, e_k = n_k - n0, and g_k the face's dual basis (b_k = g_k . (p - v0))."""
    n0 = (shading[f, 0, 0], shading[f, 0, 1], shading[f, 0, 2])
    e1 = _sub((shading[f, 1, 0], shading[f, 1, 1], shading[f, 1, 2]), n0)
    e2 = _sub((shading[f, 2, 0], shading[f, 2, 1], shading[f, 2, 2]), n0)
    raw = axpy(b1, e1, axpy(b2, e2, n0))
    length = math.sqrt(dot(raw, raw))
    g1 = (dual[f, 0, 0], dual[f, 0, 1], dual[f, 0, 2])
    g2 = (dual[f, 1, 0], dual[f, 1, 1], dual[f, 1, 2])
    return scale(1.0 / length, raw), length, e1, e2, g1, g2


@_jit
def shading_differential(normal, length, e1, e2, g1, g2, dp):
    """D N = (I - N N^T) (e1 g1^T + e2 g2^T) D p / |raw|."""
    m = axpy(dot(g1, dp), e1, scale(dot(g2, dp), e2))
    return scale(1.0 / length, axpy(-dot(normal, m), normal, m))


@_jit
def reflect(w, dwu, dwv, n, dnu, dnv):
    """Mirror reflection r = w - 2 (w . n) n with its differentials."""
    c = dot(w, n)
    cu = dot(dwu, n) + dot(w, dnu)
    cv = dot(dwv, n) + dot(w, dnv)
    return (axpy(-2.0 * c, n, w), axpy(-2.0 * cu, n, axpy(-2.0 * c, dnu, dwu)),
            axpy(-2.0 * cv, n, axpy(-2.0 * c, dnv, dwv)))


@_jit
def _box(p, w, medium, substrate, sc):
    """Nearest of the substrate's walls and bottom that the ray meets (leaving from inside,
    entering from air): (t, plane k of BOX_PLANES), (inf, -1) for none."""
    best, which = math.inf, -1
    for k in range(5):
        axis, sign, outward = BOX_PLANES[k]
        wa = w[axis]
        if abs(wa) <= 1e-12:
            continue
        if not ((medium == substrate and wa * outward > 0.0) or (medium == AIR and wa * outward < 0.0)):
            continue
        t = (sign * sc.half - p[axis]) / wa
        if not (t > 1e-9 and t < best):
            continue
        inside = True
        for j in range(3):
            if j != axis:
                c = p[j] + t * w[j]
                inside &= (0.0 <= c <= sc.thickness) if j == 2 else abs(c) <= sc.half
        if inside:
            best, which = t, k
    return best, which


@_jit
def _box_normal(k):
    axis, _, outward = BOX_PLANES[k]
    return (outward if axis == 0 else 0.0, outward if axis == 1 else 0.0, outward if axis == 2 else 0.0)


@_jit
def _over_print(p, w, sc) -> bool:
    """Whether a ray in air comes down onto the printed square from above the print."""
    if not (w[2] < 0.0 and p[2] > sc.top_max):
        return False
    s = (sc.thickness - p[2]) / w[2]
    return abs(p[0] + s * w[0]) <= sc.half and abs(p[1] + s * w[1]) <= sc.half


@_jit
def _next_event(d, row, medium, clear, released, handle, ray, wait_at_top, substrate, v0, plane, dual, neighbour, sc):
    """The photon's next event: (kind, face or box plane, distance), kind one of MESH, TOP, BOX,
    RECEIVER, ESCAPED, INSIDE_TOP or, with ``wait_at_top``, AT_TOP (its next event is the top).
    Embree (scene ``handle``, ``ray`` buffer) is asked for the face of photons in air or in an
    element, except where no face can come first: in air going down below every element, after
    leaving a clear face (``clear``, :mod:`operators.mesh.culling`), or, ``released`` (the
    photon waited at the top, where no face came before the plane z = thickness), when the top
    comes before that plane."""
    p, w = vec(row, P), vec(row, W)
    in_air, in_sub = medium == AIR, medium == substrate
    best, kind, which = math.inf, ESCAPED, -1
    over = in_air and _over_print(p, w, sc)
    t_top = math.inf
    if over and not wait_at_top:
        t_top = solve_hit(d, sc.thickness, p[0], p[1], p[2], w[0], w[1], w[2], -sc.half, sc.spacing, sc.zlo,
                          sc.zstart, sc.zhi, sc.slope_x, sc.slope_y)
    skip = clear or (in_air and w[2] < 0.0 and p[2] < sc.lowest) or (released and t_top < (sc.thickness - p[2]) / w[2])
    face = -1
    if handle != 0 and not in_sub and not skip:
        face = first_face(handle, ray, p[0] + START_OFFSET * w[0], p[1] + START_OFFSET * w[1],
                          p[2] + START_OFFSET * w[2], w[0], w[1], w[2])
    if face >= 0:
        f, t, _, _ = _face_hit(p, w, face, v0, plane, dual, neighbour)
        if t > MIN_FACE_DISTANCE and t < best:
            best, kind, which = t, MESH, f
    if over:
        # Nothing lies between the print and a ray above it (elements keep out of the substrate's
        # box), so while waiting the top comes next unless a face comes before z = thickness.
        if wait_at_top and not best < (sc.thickness - p[2]) / w[2]:
            return AT_TOP, -1, 0.0
        if t_top < best:
            best, kind, which = t_top, TOP, -1
    t, k = _box(p, w, medium, substrate, sc)
    if t < best:
        best, kind, which = t, BOX, k
    if in_air and w[2] < 0.0:
        t = (sc.receiver_z - p[2]) / w[2]
        if t < best:
            best, kind, which = t, RECEIVER, -1
    if in_sub and w[2] > 0.0:
        t = (sc.thickness - p[2]) / max(w[2], 1e-12)
        if t < best:
            best, kind, which = t, INSIDE_TOP, -1
    return kind, which, best


@_jit
def event_surface(d, row, kind, which, t, shading, dual, plane, v0, sc):
    """The surface of an event at distance t: (plane normal, outward normal, D_u N, D_v N, jet,
    moved state p', D p'); the jet only on the top, the normal's derivative only on faces and the top."""
    p, dpu, dpv = vec(row, P), vec(row, DPU), vec(row, DPV)
    w, dwu, dwv = vec(row, W), vec(row, DWU), vec(row, DWV)
    jet = (0.0, 0.0, 0.0, 0.0, 0.0)
    if kind == MESH:
        n_plane = _row3(plane, which)
    elif kind == TOP:
        jet = surface_jet_at(d, p[0] + t * w[0], p[1] + t * w[1], -sc.half, sc.spacing)
        n_plane = height_field_normal(jet[0], jet[1])
    elif kind == BOX:
        n_plane = _box_normal(which)
    else:
        n_plane = UP
    q, dqu, dqv = transfer(p, dpu, dpv, w, dwu, dwv, t, n_plane)
    outward, dnu, dnv = n_plane, ZERO, ZERO
    if kind == MESH:
        outward, length, e1, e2, g1, g2 = face_shading(q, which, v0, dual, shading)
        dnu = shading_differential(outward, length, e1, e2, g1, g2, dqu)
        dnv = shading_differential(outward, length, e1, e2, g1, g2, dqv)
    elif kind == TOP:
        dnu = normal_differential(jet[2], jet[3], jet[4], n_plane, dqu)
        dnv = normal_differential(jet[2], jet[3], jet[4], n_plane, dqv)
    return n_plane, outward, dnu, dnv, jet, q, dqu, dqv


@_jit
def interface(w, dwu, dwv, n_plane, outward, dnu, dnv, n_solid):
    """Which side the photon comes from and how it leaves: (entering, facing sign, eta, refracted
    w', D w', cos_i, cos_t, through) with through False under total internal reflection (then w'
    is the reflection)."""
    entering = dot(w, n_plane) < 0.0
    sign = 1.0 if entering else -1.0
    eta = 1.0 / n_solid if entering else n_solid
    facing, dfu, dfv = scale(sign, outward), scale(sign, dnu), scale(sign, dnv)
    r, ru, rv, ci, ct, k = refract(w, dwu, dwv, facing, dfu, dfv, eta)
    if k <= 0.0:
        r, ru, rv = reflect(w, dwu, dwv, facing, dfu, dfv)
    return entering, sign, eta, r, ru, rv, ci, ct, k > 0.0


@_jit
def _advance_one(d, i, state, medium, channel, status, clear, released, handle, ray, kind_out, which_out, t_out,
                 replay, lost_fresnel, wait_at_top, substrate, face_element, face_clear, indices, v0, plane, dual,
                 shading, neighbour, sc) -> None:
    """One event of photon i (see :func:`advance`)."""
    row = state[i]
    if replay:
        kind, which, t = kind_out[i], which_out[i], t_out[i]
    else:
        kind, which, t = _next_event(d, row, medium[i], clear[i], released, handle, ray, wait_at_top, substrate, v0,
                                     plane, dual, neighbour, sc)
        kind_out[i], which_out[i], t_out[i] = kind, which, t
    clear[i] = False
    if kind == AT_TOP:
        status[i] = WAITING
        return
    if kind == ESCAPED or kind == INSIDE_TOP:
        status[i] = LOST
        return
    n_plane, outward, dnu, dnv, _, q, dqu, dqv = event_surface(d, row, kind, which, t, shading, dual, plane, v0, sc)
    put(row, P, q)
    put(row, DPU, dqu)
    put(row, DPV, dqv)
    if kind == RECEIVER:
        status[i] = LANDED
        return
    solid = face_element[which] if kind == MESH else substrate
    entering, _, eta, r, ru, rv, ci, ct, through = interface(
        vec(row, W), vec(row, DWU), vec(row, DWV), n_plane, outward, dnu, dnv, indices[solid, channel[i]])
    put(row, W, r)
    put(row, DWU, ru)
    put(row, DWV, rv)
    if through:
        if sc.fresnel:
            kept = fresnel(ci, ct, eta)
            lost_fresnel[i] += row[FLUX] * (1.0 - kept)
            row[FLUX] *= kept
        medium[i] = solid if entering else AIR
        clear[i] = kind == MESH and not entering and face_clear[which] and dot(r, n_plane) >= CLEAR_COS


@_kernel
def advance(d, state, medium, channel, status, clear, released, handle, kind_out, which_out, t_out, replay,
            lost_fresnel, before, wait_at_top, substrate, face_element, face_clear, indices, v0, plane, dual, shading,
            neighbour, sc) -> None:
    """One event of every photon with status UNDER_WAY (in place): ``state`` (N, STATE),
    ``medium`` (N,) (AIR, an element, or ``substrate``), ``clear`` (N,) whether it left a face
    with no element in front (``face_clear`` (F,), :mod:`operators.mesh.culling`), ``released``
    whether the photons start where they waited at the top; ``handle`` the elements' Embree scene
    (:class:`operators.mesh.embree_native.EmbreeTriangles`; 0 for none);
    records kind_out, which_out (face or box plane) and t_out (N,) for :func:`retreat`, or with
    ``replay`` takes the events from them (recorded at the same heights: no search); adds the
    flux that Fresnel reflection takes into ``lost_fresnel``; copies the state of each photon under
    way into ``before`` (N, STATE) first, unless it has no rows. Ends photons: LANDED on the
    receiver, LOST (escaped or inside the glass under the top), WAITING before the top with
    ``wait_at_top``. ``indices`` (K + 1, c): refractive index of each element and the substrate."""
    blocks = (state.shape[0] + BLOCK - 1) // BLOCK
    for b in nb.prange(blocks):
        _advance_block(b * BLOCK, min(state.shape[0], (b + 1) * BLOCK), d, state, medium, channel, status, clear,
                       released, handle, kind_out, which_out, t_out, replay, lost_fresnel, before, wait_at_top,
                       substrate, face_element, face_clear, indices, v0, plane, dual, shading, neighbour, sc)


@_call
def _advance_block(lo, hi, d, state, medium, channel, status, clear, released, handle, kind_out, which_out, t_out,
                   replay, lost_fresnel, before, wait_at_top, substrate, face_element, face_clear, indices, v0, plane,
                   dual, shading, neighbour, sc) -> None:
    """:func:`advance` for photons lo .. hi-1 (one thread)."""
    ray = ray_buffer()
    for i in range(lo, hi):
        if status[i] != UNDER_WAY:
            kind_out[i] = -1
            continue
        if before.shape[0]:
            before[i] = state[i]
        _advance_one(d, i, state, medium, channel, status, clear, released, handle, ray, kind_out, which_out, t_out,
                     replay, lost_fresnel, wait_at_top, substrate, face_element, face_clear, indices, v0, plane, dual,
                     shading, neighbour, sc)


@_kernel
def splat_arguments(state, status, where, sc, pos, metric, flux) -> None:
    """Pixel positions (2, N), footprint metrics (3, N) and flux (N,) of the photons on the
    receiver (flux 0 and a unit metric for the others), photon i's at column ``where[i]``."""
    k = sc.to_px
    for i in nb.prange(state.shape[0]):
        j = where[i]
        if status[i] != LANDED:
            pos[0, j] = pos[1, j] = 0.0
            metric[0, j], metric[1, j], metric[2, j] = 1.0, 0.0, 1.0
            flux[j] = 0.0
            continue
        row = state[i]
        pos[0, j] = (row[P] + sc.receiver_half) * k - 0.5
        pos[1, j] = (row[P + 1] + sc.receiver_half) * k - 0.5
        q = footprint_metric(row[DPU] * k, row[DPU + 1] * k, row[DPV] * k, row[DPV + 1] * k, sc.min_px, sc.max_px)
        metric[0, j], metric[1, j], metric[2, j] = q
        flux[j] = row[FLUX]
