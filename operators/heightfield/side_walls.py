"""Where a photon refracted into the substrate leaves it: the bottom or a side wall (docs/method.md,
"The substrate's side walls").

The substrate is the block [-W, W]^2 x [0, h + d]. A photon that enters the top goes on in a
straight line to the bottom z = 0 unless it meets a side wall x = +-W or y = +-W first. There it
is either totally reflected (|w_x| below the critical cosine sqrt(1 - 1 / n^2)) or refracted out
into the air. A total reflection mirrors the rest of the path about the wall's plane, and the
bottom and the receiver planes are symmetric under that mirror, so a reflected photon lands where
the unreflected straight path lands, mirrored about the wall: the optics trace the straight path
through the bottom and mirror its landing point and footprint (x -> 2 W sign - x). A photon that a
wall refracts leaves through that wall's plane (normal -+e_x) instead of the bottom, then falls
straight to the receiver; a reflection at the other pair of walls before it still mirrors its
landing. ``clear=False`` (``substrate.walls: absorbing``, blackened or frosted edges) loses every
photon that reaches a wall, the paper's assumption.
"""

from __future__ import annotations


from operators.kernels.numba_settings import jit_inline
from operators.optics.native import away_from_zero

# Path codes (:func:`leaving_plane`): 0 lost; else 1 + fold_x + 3 fold_y + 9 exit, with fold 0
# (none), 1 (mirrored about +W), 2 (about -W) and exit 0 (bottom), 1 (an x wall), 2 (a y wall).
LOST = 0
# Walls a photon may meet per axis before the bottom: a path that would cross the block's full
# width (|bottom point| > 3 W, a nearly horizontal ray) is lost.
FOLD_LIMIT = 3.0
# A top hit beyond this times W (rounding aside) lies outside the block: the ray passed beside it.
BESIDE = 1.0 + 1e-12

_jit = jit_inline


@_jit
def _side(x: float) -> float:
    return 1.0 if x > 0.0 else -1.0


@_jit
def leaving_plane(p1, w1, eta, half, clear):
    """The face through which a photon at p1 in the glass along w1 (w1_z < 0), glass index eta,
    leaves a block of half width ``half`` (``clear``: walls that transmit and reflect, else absorb).

    Returns (n2, c2, fx, ox, fy, oy, lost, code): the face's plane n2 . p = c2 with n2 the normal
    facing the photon (UP for the bottom, -+e_x / -+e_y for a wall it refracts through); the
    mirror x -> fx x + ox, y -> fy y + oy that total reflections at the walls apply to the landing
    point (fx, fy = +-1); ``lost``: absorbed by a wall (or crossing the block); ``code`` the
    path's code, the module's encoding of the folds and the exit (the caller sets LOST for a
    photon lost here or later). A photon whose top hit p1 lies outside the square (aimed beyond
    it, operators/emission.py: it met the surface's flat continuation, so it passed beside the
    block) is lost."""
    tb = -p1[2] / away_from_zero(w1[2])
    bx = p1[0] + tb * w1[0]
    by = p1[1] + tb * w1[1]
    cross_x = abs(bx) > half
    cross_y = abs(by) > half
    sx = _side(bx)
    sy = _side(by)
    e2 = eta * eta
    exit_x = cross_x and e2 * (1.0 - w1[0] * w1[0]) < 1.0
    exit_y = cross_y and e2 * (1.0 - w1[1] * w1[1]) < 1.0
    tx = (sx * half - p1[0]) * w1[0] / max(w1[0] * w1[0], 1e-300)
    ty = (sy * half - p1[1]) * w1[1] / max(w1[1] * w1[1], 1e-300)
    # A ray aimed beyond the square that meets the surface's flat continuation outside it passed beside the block.
    beside = abs(p1[0]) > BESIDE * half or abs(p1[1]) > BESIDE * half
    lost = (beside or (not clear and (cross_x or cross_y)) or abs(bx) > FOLD_LIMIT * half
            or abs(by) > FOLD_LIMIT * half)
    fold_x = cross_x
    fold_y = cross_y
    exit_code = 0
    n2 = (0.0, 0.0, 1.0)
    c2 = 0.0
    if exit_x and (not exit_y or tx <= ty):
        n2 = (-sx, 0.0, 0.0)
        c2 = -half
        fold_x = False
        fold_y = cross_y and ty < tx
        exit_code = 1
    elif exit_y:
        n2 = (0.0, -sy, 0.0)
        c2 = -half
        fold_x = cross_x and tx < ty
        fold_y = False
        exit_code = 2
    fx = -1.0 if fold_x else 1.0
    fy = -1.0 if fold_y else 1.0
    ox = 2.0 * sx * half if fold_x else 0.0
    oy = 2.0 * sy * half if fold_y else 0.0
    code = 1 + (0 if not fold_x else (1 if sx > 0.0 else 2)) + 3 * (0 if not fold_y else (1 if sy > 0.0 else 2)) \
        + 9 * exit_code
    return n2, c2, fx, ox, fy, oy, lost, code
