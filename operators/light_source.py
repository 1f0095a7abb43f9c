"""Emission points over an extended light (``light.shape: disc | square``, operators/scene.py).

A flash behind a diffuser is a source of uniform brightness over a disc or a square facing the
glass. Every point of it casts the point light's caustic; the extended light's caustic is their
mean. Two point sets stand for the source:

- the photon operators' (operators/emission.py, ``source_points``): the R2 low-discrepancy
  sequence (the aim points' generator) with a Cranley-Patterson shift drawn from the seed, put
  onto the source by :func:`onto_source`, an area-preserving map (a disc: radius R sqrt(u),
  angle 2 pi v);
- the exact references' (operators/wavefront/extended.py), independent of the model's,
  :func:`spiral_points`: Vogel's sunflower spiral over a disc (radius R sqrt((k + 1/2) / K),
  angle k times the golden angle), the centres of a q x q grid over a square (K = q^2).

Both give K points of equal weight, offsets (K, 2) in x, y from the light's centre, scene units.
"""

from __future__ import annotations

import math

import numpy as np

from operators.scene import Light

__all__ = ["onto_source", "spiral_points", "receiver_spread", "source_variance", "patch_variance", "moment_matched"]

_GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))


def onto_source(light: Light, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Points (u, v) of the unit square (N,) each, put onto ``light``'s disc or square by an
    area-preserving map: offsets (N, 2) float64 from its centre."""
    if light.shape == "square":
        return np.stack([(u - 0.5) * light.size, (v - 0.5) * light.size], axis=1)
    radius, angle = 0.5 * light.size * np.sqrt(u), 2.0 * math.pi * v
    return np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)


def spiral_points(light: Light, count: int) -> np.ndarray:
    """About ``count`` points over ``light``'s disc (Vogel's spiral, exactly ``count``) or square
    (the centres of a q x q grid, q = ceil(sqrt(count))): offsets (K, 2) float64 from its centre."""
    if light.shape == "square":
        side = math.ceil(math.sqrt(count))
        centres = ((np.arange(side) + 0.5) / side - 0.5) * light.size
        x, y = np.meshgrid(centres, centres, indexing="xy")
        return np.stack([x.ravel(), y.ravel()], axis=1)
    k = np.arange(count, dtype=np.float64)
    radius, angle = 0.5 * light.size * np.sqrt((k + 0.5) / count), k * _GOLDEN_ANGLE
    return np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)


def receiver_spread(light: Light, thickness: float, index: float, screen_distance: float) -> float:
    """How far (scene units) the caustic moves on the receiver per unit the light moves within its
    plane, for light through flat glass of ``thickness`` and refractive ``index`` onto a screen
    ``screen_distance`` below its bottom, near the axis: (s + t / n) / (L - t), L the light's
    height above the bottom. An extended light of size a blurs the point light's caustic over
    about a times this (docs/method.md, "The extended light")."""
    return (screen_distance + thickness / index) / (light.position[2] - thickness)


def source_variance(light: Light) -> float:
    """The source's second moment per axis about its centre (scene units^2): a^2 / 16 for a disc
    of diameter a, a^2 / 12 for a square of side a, 0 for a point."""
    if not light.extended:
        return 0.0
    return light.size ** 2 / (16.0 if light.shape == "disc" else 12.0)


def patch_variance(light: Light, count: int) -> float:
    """The second moment per axis (scene units^2) of the blur that stands for the patch of the
    source each of ``count`` emission points covers: three times a square patch's (area / count,
    variance area / (12 count)), so that it smooths the points' comb (at most the source's own
    second moment). Measured on print_lines (docs/method.md, "The extended light"): at 64 points a
    square patch's variance leaves 1.9-2.8% of the exact caustic, this 1.9-2.6%."""
    area = light.size ** 2 * (math.pi / 4.0 if light.shape == "disc" else 1.0)
    return min(area / (4.0 * count), source_variance(light))


def moment_matched(offsets: np.ndarray, light: Light, residual: float) -> np.ndarray:
    """``offsets`` (K, 2) centred and scaled so that, blurred by an isotropic spot of variance
    ``residual`` per axis, they keep the source's centre and second moment per axis exactly."""
    centred = offsets - offsets.mean(axis=0)
    spread = float((centred ** 2).sum(axis=1).mean()) / 2.0
    if spread == 0.0:
        return centred
    return centred * math.sqrt(max(source_variance(light) - residual, 0.0) / spread)
