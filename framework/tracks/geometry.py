"""Where each height sample lies relative to a track's path: arc length, lateral distance and
the distance beyond the path's ends.

A track's path is fixed during a fit (the tool path or the design's skeleton); the bead moves
across it through its offset profile. So the coordinates of the samples near a path are computed
once, with numpy, and every render afterwards is a gather and an elementwise formula
(framework/tracks/track_heights.py). Lengths in scene units; the grid's samples lie at
linspace(-W, W, m) in x (columns) and y (rows), framework/core/problem.py HeightGrid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["PathSamples", "path_samples", "resampled_path", "path_length", "frame_at"]

# Pixels per block of the nearest-segment search (bounds its memory: block x segments doubles).
BLOCK = 4096


def path_length(points: np.ndarray) -> float:
    """The polyline's length (its units)."""
    return float(np.sum(np.hypot(*np.diff(points, axis=0).T)))


def frame_at(points: np.ndarray, arc: float) -> tuple[np.ndarray, np.ndarray]:
    """The polyline's vertex at (or first past) arc length ``arc`` and the unit normal to the left of
    the segment that ends there, each (2,)."""
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    i = int(np.clip(np.searchsorted(along, arc), 1, len(points) - 1))
    tangent = points[i] - points[i - 1]
    tangent = tangent / max(float(np.hypot(*tangent)), 1e-12)
    return points[i], np.array([-tangent[1], tangent[0]])


def resampled_path(points: np.ndarray, spacing: float) -> np.ndarray:
    """The polyline (k, 2) resampled at equal arc-length steps of at most ``spacing``, ends kept."""
    points = np.asarray(points, dtype=np.float64)
    steps = np.hypot(*np.diff(points, axis=0).T)
    keep = np.concatenate([[True], steps > 1e-12])  # repeated points carry no direction
    points = points[keep]
    if len(points) < 2:
        raise ValueError("a track's path needs two distinct points at least")
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    count = max(2, int(math.ceil(arc[-1] / spacing)) + 1)
    at = np.linspace(0.0, arc[-1], count)
    return np.stack([np.interp(at, arc, points[:, 0]), np.interp(at, arc, points[:, 1])], axis=1)


@dataclass(frozen=True)
class PathSamples:
    """The grid samples within ``reach`` of a path and their coordinates along it.

    Attributes:
        index: (p,) flat indices (row * m + column) of the samples.
        s: (p,) arc length of the nearest point of the path, in [0, length].
        u: (p,) signed distance across the path (positive to the left of its direction).
        beyond: (p,) distance past the path's nearer end along its end direction (0 beside it),
            so that a bead's end is round: its cross-section taken over hypot(u - offset, beyond).
        length: The path's length.
    """

    index: np.ndarray
    s: np.ndarray
    u: np.ndarray
    beyond: np.ndarray
    length: float


def path_samples(points: np.ndarray, half_width: float, resolution: int, reach: float) -> PathSamples:
    """The samples of the (m, m) grid on [-W, W]^2 within ``reach`` of the polyline ``points`` (k, 2)
    (x, y), with their path coordinates (nearest segment by brute force over blocks of samples)."""
    points = np.asarray(points, dtype=np.float64)
    h = 2.0 * half_width / (resolution - 1)
    low = np.floor((points.min(axis=0) - reach + half_width) / h).astype(int)
    high = np.ceil((points.max(axis=0) + reach + half_width) / h).astype(int)
    low, high = np.clip(low, 0, resolution - 1), np.clip(high, 0, resolution - 1)
    col_grid, row_grid = np.meshgrid(np.arange(low[0], high[0] + 1), np.arange(low[1], high[1] + 1))
    cols, rows = col_grid.ravel(), row_grid.ravel()
    xy = np.stack([-half_width + cols * h, -half_width + rows * h], axis=1)
    a, b = points[:-1], points[1:]
    seg = b - a
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    arc0 = np.concatenate([[0.0], np.cumsum(seg_len)])[:-1]
    length = float(arc0[-1] + seg_len[-1])
    s_out, u_out, d_out = (np.empty(len(xy)) for _ in range(3))
    for start in range(0, len(xy), BLOCK):
        p = xy[start:start + BLOCK, None, :] - a[None]  # (q, k-1, 2)
        t = np.clip(np.einsum("qkc,kc->qk", p, seg) / seg_len**2, 0.0, 1.0)
        dist = np.hypot(*(p - t[..., None] * seg[None]).transpose(2, 0, 1))
        k = np.argmin(dist, axis=1)
        q = np.arange(len(k))
        tk, pk, sk, lk = t[q, k], p[q, k], seg[k], seg_len[k]
        s_out[start:start + BLOCK] = arc0[k] + tk * lk
        cross = (sk[:, 0] * pk[:, 1] - sk[:, 1] * pk[:, 0]) / lk  # signed distance to the segment's line
        along = (sk[:, 0] * pk[:, 0] + sk[:, 1] * pk[:, 1]) / lk  # along it, from its start
        first, last = (k == 0) & (along < 0.0), (k == len(seg) - 1) & (along > lk)
        d_out[start:start + BLOCK] = np.where(first, -along, np.where(last, along - lk, 0.0))
        inside = ~(first | last)
        # Beside the path: the distance to it, signed by the side; past an end: across the end's line.
        u_out[start:start + BLOCK] = np.where(inside, np.sign(cross) * dist[q, k], cross)
    near = np.hypot(u_out, d_out) <= reach
    return PathSamples(index=(rows * resolution + cols)[near], s=s_out[near], u=u_out[near], beyond=d_out[near],
                       length=length)
