"""Twin ridges: two low ridges side by side that may be one thin tall bead between them.

A bead past its focus lights a band with bright edges (its folds) and a dark middle. A fit whose
rays do not cross (a free grid of heights, or the transport's monotone map) explains that band
by two low ridges, one under each bright edge. Where two tracks of a fit's skeleton run side by
side at a steady distance, one bead on their midline (the order-reversing map across the band) is
the other hypothesis (framework/tracks/ambiguity.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from framework.tracks.geometry import resampled_path
from framework.tracks.track_set import Track, TrackSet

__all__ = ["Twins", "twin_pairs"]

STEP_MM = 0.25  # paths compared at this spacing
MIN_OVERLAP = 0.6  # the shorter path runs beside the other over this share of its length at least
MAX_SPREAD = 0.3  # the distance between them varies by this share of its median at most (quartiles)
MAX_SEPARATION = 3.0  # that median is at most this many times the pair's mean width, and at most the shorter's length


@dataclass(frozen=True)
class Twins:
    """Tracks ``first`` and ``second`` (indices) run side by side ``separation_mm`` apart; ``midline``
    (k, 2), mm: the path between them, carried on by half their separation at both ends (the folds
    of a bead's band end short of the bead's own ends, and so do the ridges under them)."""

    first: int
    second: int
    separation_mm: float
    midline: np.ndarray


def _extended(path: np.ndarray, reach: float) -> np.ndarray:
    """The path (k, 2) carried on straight by ``reach`` at both ends."""
    ahead, behind = path[-1] - path[-2], path[0] - path[1]
    ahead, behind = (v / max(float(np.hypot(*v)), 1e-12) for v in (ahead, behind))
    return np.vstack([path[0] + reach * behind, path, path[-1] + reach * ahead])


def _side_by_side(first: Track, second: Track) -> tuple[np.ndarray, float] | None:
    """The midline (k, 2) mm and median distance of two tracks that run side by side, or None."""
    a, b = resampled_path(first.path, STEP_MM), resampled_path(second.path, STEP_MM)
    if len(a) > len(b):
        a, b = b, a
    _, nearest = cKDTree(b).query(a)
    inside = (nearest > 0) & (nearest < len(b) - 1)  # beside b, not past its ends
    if inside.mean() < MIN_OVERLAP or inside.sum() < 2:
        return None
    near, far = a[inside], b[nearest[inside]]
    gaps = np.hypot(*(far - near).T)
    median = float(np.median(gaps))
    q1, q3 = np.percentile(gaps, [25, 75])
    mean_width = 0.5 * (float(np.mean(first.width)) + float(np.mean(second.width)))
    if (median <= 0.0 or q3 - q1 > MAX_SPREAD * median or median > MAX_SEPARATION * mean_width
            or min(first.length, second.length) < median):
        return None
    return _extended(0.5 * (near + far), 0.5 * median), median


def twin_pairs(tracks: TrackSet) -> list[Twins]:
    """Every pair of tracks that run side by side (module docstring), in the tracks' order."""
    found = []
    for i in range(len(tracks.tracks)):
        for j in range(i + 1, len(tracks.tracks)):
            beside = _side_by_side(tracks.tracks[i], tracks.tracks[j])
            if beside is not None:
                found.append(Twins(i, j, beside[1], beside[0]))
    return found
