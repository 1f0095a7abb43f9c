"""The two halves of an operator's light path around the print, for starts that invert it
(framework/reconstruction/starts/transport.py).

Every operator traces light from the point light, through whatever lies above the print, into the
printed top, through the substrate, out of its flat bottom (z = 0) and through whatever lies below
onto the receiver. The printed heights change only what happens between the top and the bottom,
so an operator that offers a start to be computed from its data declares ``has_light_path`` and
exposes the two fixed halves (operators/image_operator.py):

- ``arrivals(photons)``: where and from which direction its photons meet the plane of the
  substrate top z = h when the print is flat (:class:`Arrivals`);
- ``land_from_bottom(points, directions)``: where rays that leave the bottom at ``points`` (N, 2)
  along ``directions`` (N, 3), in air, reach the receiver plane.

The height-field operator computes both in closed form (straight lines in air), the mesh-scene
operator traces them through its optical elements with its own tracer. The helpers here refract
through the flat faces of the substrate (numpy, float64).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Arrivals", "refract_down", "flat_exit", "straight_landing"]


@dataclass(frozen=True)
class Arrivals:
    """Photons where they meet the plane z = h of a flat print's top.

    Attributes:
        points: (N, 2) x, y on the plane, scene units.
        directions: (N, 3) unit directions of travel there (z < 0).
        flux: (N,) W per photon.
        photon: (N,) the photons' indices in the operator's emission order (those that miss the
            top are left out).
    """

    points: np.ndarray
    directions: np.ndarray
    flux: np.ndarray
    photon: np.ndarray


def refract_down(direction: np.ndarray, eta: float) -> np.ndarray:
    """Unit directions (N, 3) after a horizontal interface (normal +z) for rays going down (z < 0),
    eta = n_before / n_after; NaN where the light is totally reflected."""
    cos_i = -direction[:, 2]
    k = 1.0 - eta ** 2 * (1.0 - cos_i ** 2)
    root = np.sqrt(np.where(k >= 0.0, k, np.nan))
    out = eta * direction
    out[:, 2] += eta * cos_i - root
    return out


def flat_exit(points: np.ndarray, incident: np.ndarray, index: float, top: float) -> tuple[np.ndarray, np.ndarray]:
    """Rays through a flat slab: entering its top at ``points`` (N, 2) along unit ``incident``
    (N, 3), crossing ``top`` of glass of refractive ``index``: where (N, 2) and along which unit
    direction (N, 3) they leave the bottom z = 0."""
    inside = refract_down(incident, 1.0 / index)
    exit_points = points + inside[:, :2] * (top / -inside[:, 2:3])
    return exit_points, refract_down(inside, index)


def straight_landing(points: np.ndarray, directions: np.ndarray, receiver_z: float) -> np.ndarray:
    """Receiver points (N, 2) of straight rays from ``points`` (N, 2) on z = 0 along ``directions``
    (N, 3) to the plane z = receiver_z < 0; NaN for rays not going down."""
    going = directions[:, 2] < 0.0
    run = np.where(going, receiver_z / np.where(going, directions[:, 2], -1.0), np.nan)
    return points + directions[:, :2] * run[:, None]
