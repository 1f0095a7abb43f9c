"""Orders that keep nearby points together (Morton, or Z-order, codes): the mesh kernels touch
the same faces and the same Embree nodes for photons next to each other in such an order, so
those stay in the caches.
"""

from __future__ import annotations

import numpy as np

__all__ = ["morton_order", "crossing_order"]

# Bits per axis of the codes (3 x 20 bits fit an unsigned 64-bit integer).
BITS = 20


def _spread(q: np.ndarray, axes: int) -> np.ndarray:
    """The bits of ``q`` (uint64 < 2^BITS) moved to every ``axes``-th bit."""
    out = np.zeros_like(q)
    for bit in range(BITS):
        out |= ((q >> np.uint64(bit)) & np.uint64(1)) << np.uint64(axes * bit)
    return out


def morton_order(points: np.ndarray) -> np.ndarray:
    """The permutation (N,) that sorts ``points`` (N, k), k = 1 .. 3, by their Morton code on a grid
    of 2^BITS cells per axis over their bounding box (stable: equal codes keep their order)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    scale = (2 ** BITS - 1) / np.where(hi > lo, hi - lo, 1.0)
    cells = np.clip((points - lo) * scale, 0, 2 ** BITS - 1).astype(np.uint64)
    code = np.zeros(len(points), dtype=np.uint64)
    for axis in range(points.shape[1]):
        code |= _spread(cells[:, axis], points.shape[1]) << np.uint64(axis)
    return np.argsort(code, kind="stable")


def crossing_order(position: np.ndarray, direction: np.ndarray, z: float, chunk: int) -> np.ndarray:
    """Photons (position, direction (N, 3), going down) reordered within each run of ``chunk``: by
    the Morton code of where they cross the plane ``z``. The permutation (N,) keeps every photon
    in its run, so runs (and what is summed over each) keep their photons."""
    crossing = position[:, :2] + ((z - position[:, 2]) / direction[:, 2])[:, None] * direction[:, :2]
    order = np.arange(len(position))
    for start in range(0, len(position), chunk):
        stop = min(start + chunk, len(position))
        order[start:stop] = start + morton_order(crossing[start:stop])
    return order
