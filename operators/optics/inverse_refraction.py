"""Inverse refraction for caustic design: which surface normal sends a ray to a given receiver point.

The printed top surface is the only freeform interface; below it the glass ends in the flat
substrate bottom (z = 0, normal +z) and the receiver plane lies at z = receiver_z < 0. For a
point P on the top surface, lit from the light along the unit direction i, and a target point T
on the receiver, :func:`glass_directions` finds the direction t inside the glass whose ray leaves
through the flat bottom (Snell at z = 0) and lands on T; :func:`snell_normals` then gives the top
surface's normal that refracts i into t. Arrays are numpy, float64, points and directions (N, 3).
"""

from __future__ import annotations

import numpy as np

# Bisection steps of the in-glass ray's horizontal run: 2^-60 of the run, below float64 rounding.
BISECTION_STEPS = 60


def glass_directions(points: np.ndarray, targets: np.ndarray, index: float, receiver_z: float) -> np.ndarray:
    """Unit directions t (N, 3) inside the glass from ``points`` (N, 3), z > 0, to the flat bottom
    z = 0 such that, refracted there into air, the rays reach ``targets`` (N, 2 or 3; their x, y)
    on the receiver plane z = ``receiver_z`` < 0.

    The ray stays in the vertical plane through P and T; with a the horizontal run in the glass,
    b = D - a the run in air (D the horizontal distance from P to T), H1 = P_z and H2 = -receiver_z,
    Snell at the bottom reads n a / |(a, H1)| = b / |(b, H2)|, whose left side grows and right
    side falls with a: one root in [0, D], found by bisection (all rays at once).
    """
    if not (np.isfinite(index) and index >= 1.0):
        raise ValueError(f"refractive index {index!r} must be >= 1")
    if not receiver_z < 0.0:
        raise ValueError(f"receiver_z={receiver_z!r} must lie below the substrate bottom (z < 0)")
    if np.any(points[:, 2] <= 0.0):
        raise ValueError("points must lie above the substrate bottom (z > 0)")
    offset = targets[:, :2] - points[:, :2]
    distance = np.linalg.norm(offset, axis=1)
    h1, h2 = points[:, 2], -float(receiver_z)
    lo, hi = np.zeros_like(distance), distance.copy()
    for _ in range(BISECTION_STEPS):
        a = 0.5 * (lo + hi)
        b = distance - a
        too_far = index * a / np.hypot(a, h1) > b / np.hypot(b, h2)
        hi = np.where(too_far, a, hi)
        lo = np.where(too_far, lo, a)
    run = 0.5 * (lo + hi)
    unit = np.divide(offset, distance[:, None], out=np.zeros_like(offset), where=distance[:, None] > 0)
    direction = np.concatenate([unit * run[:, None], -h1[:, None]], axis=1)
    return direction / np.linalg.norm(direction, axis=1, keepdims=True)


def snell_normals(incident: np.ndarray, transmitted: np.ndarray, index: float) -> np.ndarray:
    """Unit normals (N, 3), facing up (+z, toward the light), of an air-to-glass interface that
    refracts unit ``incident`` into unit ``transmitted`` (Snell in vector form: the normal is
    parallel to i - n t)."""
    normal = incident - index * transmitted
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    return np.where(normal[:, 2:3] < 0.0, -normal, normal)


def deflection_angle(tilt: float, index: float) -> float:
    """Angle (radians) by which glass of refractive ``index`` with a top tilted by ``tilt`` (radians)
    over a flat bottom turns a ray that meets it vertically: refracted at the top (Snell), then
    leaving the bottom; 0 for a flat top. Raises for a tilt whose ray is totally reflected."""
    inside = tilt - np.arcsin(np.sin(tilt) / index)  # the ray's angle to the vertical in the glass
    sine = index * np.sin(inside)
    if abs(sine) >= 1.0:
        raise ValueError(f"a top tilted by {np.degrees(tilt):.1f} degrees reflects the light totally at the bottom; "
                         "lower constraints.max_slope")
    return float(np.arcsin(sine))


def flat_magnification(light_height: float, thickness: float, index: float, receiver_z: float) -> float:
    """Paraxial scale k from the substrate top to the receiver for flat glass: a point at distance r
    from the axis on the top lands at k r (ray slope r / (z_L - h) in air, / n in the glass)."""
    return 1.0 + (thickness / index - receiver_z) / (light_height - thickness)
