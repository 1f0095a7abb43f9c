"""Defects read from fitted tracks against their nominal profiles: where each bead is interrupted,
too low or high, too wide or narrow, displaced, and where glass lies off the beads (a drop).

A gap the fit opened in a track is an interruption of its length. Per knot of each track, the
fitted height, width and offset are compared with the nominal ones (the tool path's or the
design's): a change beyond its tolerance is a deviation of that kind, the largest one (in
tolerances) names the knot; runs of neighbouring knots of one kind are one defect, placed at the
run's middle on the fitted bead, as long as the run. Excess material is a drop the global search
placed off the beads (framework/tracks/track_search.py), or glass the residual grid holds in a
connected blob, of at least ``min_drop_mm3`` either.

Each defect comes with a confidence z, the standard deviations of the change the photo confirms
(framework/tracks/track_report.py: the misfit's growth when the defect is undone, in pixel noise
variances, square-rooted); a defect under ``z_min`` is not reported.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from framework.defects.fit import Defect
from framework.tracks.geometry import frame_at, resampled_path
from framework.tracks.track_set import GAP_EDGE_MM, Drop, Track, TrackSet

__all__ = ["TrackTolerances", "KnotRun", "deviation_runs", "track_defects", "drop_defects", "placed_drop_defects",
           "gap_defects"]


@dataclass(frozen=True)
class TrackTolerances:
    """What counts as a deviation: relative height and width changes, a shift in mm, the share of
    the nominal height below which a bead is interrupted, the smallest drop (mm^3) and confidence."""

    height: float = 0.15
    width: float = 0.2
    offset_mm: float = 0.3
    interrupted: float = 0.3
    min_drop_mm3: float = 0.1
    z_min: float = 3.0


@dataclass(frozen=True)
class KnotRun:
    """A run of knots [first, last] of one track deviating by one kind."""

    track: int
    kind: str
    first: int
    last: int


def _kinds(nominal: Track, fitted: Track, tol: TrackTolerances) -> list[str]:
    """Each knot's deviation kind ('' within tolerance)."""
    ratio_h = fitted.height / np.maximum(nominal.height, 1e-9)
    ratio_w = fitted.width / np.maximum(nominal.width, 1e-9)
    scores = np.stack([np.abs(ratio_h - 1.0) / tol.height, np.abs(ratio_w - 1.0) / tol.width,
                       np.abs(fitted.offset - nominal.offset) / tol.offset_mm])
    kinds = []
    for k in range(nominal.knots):
        if ratio_h[k] < tol.interrupted:
            kinds.append("interruption")
            continue
        which = int(np.argmax(scores[:, k]))
        if scores[which, k] <= 1.0:
            kinds.append("")
        elif which == 0:
            kinds.append("too_low" if ratio_h[k] < 1.0 else "too_high")
        elif which == 1:
            kinds.append("too_narrow" if ratio_w[k] < 1.0 else "too_wide")
        else:
            kinds.append("displaced")
    return kinds


def deviation_runs(nominal: TrackSet, fitted: TrackSet, tol: TrackTolerances) -> list[KnotRun]:
    """The runs of knots deviating by one kind, track by track."""
    runs = []
    for index, (a, b) in enumerate(zip(nominal.tracks, fitted.tracks)):
        kinds = _kinds(a, b, tol)
        start = 0
        for k in range(1, len(kinds) + 1):
            if k == len(kinds) or kinds[k] != kinds[start]:
                if kinds[start]:
                    runs.append(KnotRun(index, kinds[start], start, k - 1))
                start = k
    return runs


def _on_bead(track: Track, arc: float) -> tuple[float, float]:
    """(x, y) in mm of the fitted bead's centre at arc length ``arc`` (its offset applied)."""
    point, normal = frame_at(resampled_path(track.path, 0.05), arc)
    x, y = point + float(np.interp(arc, track.knot_arcs(), track.offset)) * normal
    return float(x), float(y)


def _place(track: Track, run: KnotRun) -> tuple[float, float, float]:
    """(x, y, length) in mm of a run on the fitted bead."""
    arcs = track.knot_arcs()
    x, y = _on_bead(track, 0.5 * (arcs[run.first] + arcs[run.last]))
    return x, y, float((run.last - run.first + 1) * (arcs[1] - arcs[0]))


def _size(nominal: Track, fitted: Track, run: KnotRun) -> tuple[float, float, float]:
    """(size as the report measures it, peak height change mm, volume change mm^3) of a run."""
    span = slice(run.first, run.last + 1)
    spacing = nominal.knot_arcs()[1]
    if run.kind in ("interruption", "too_low", "too_high"):
        size = float(np.mean(1.0 - fitted.height[span] / nominal.height[span]))
    elif run.kind in ("too_wide", "too_narrow"):
        size = float(np.mean(fitted.width[span] / nominal.width[span] - 1.0))
    else:
        size = float(np.mean(fitted.offset[span] - nominal.offset[span]))
    change = fitted.height[span] - nominal.height[span]
    peak = float(change[np.argmax(np.abs(change))])
    area = lambda t: t.height[span] * t.width[span]  # noqa: E731 (the same factor for both shapes aside)
    volume = float(np.sum(area(fitted) - area(nominal)) * spacing)
    return size, peak, volume


def track_defects(nominal: TrackSet, fitted: TrackSet, tol: TrackTolerances,
                  confidence: Callable[[KnotRun], float]) -> list[Defect]:
    """The beads' defects (module docstring); ``confidence(run)``: the change's z."""
    defects = []
    for run in deviation_runs(nominal, fitted, tol):
        z = confidence(run)
        if z < tol.z_min:
            continue
        a, b = nominal.tracks[run.track], fitted.tracks[run.track]
        x, y, length = _place(b, run)
        size, peak, volume = _size(a, b, run)
        defects.append(Defect(run.kind, x, y, length, size, peak, volume, evidence=z * z, confidence=z,
                              model=f"track:{a.name}", params=(float(run.first), float(run.last))))
    return defects


def drop_defects(residual_mm: np.ndarray, cell_mm: float, tol: TrackTolerances,
                 confidence: Callable[[np.ndarray], float]) -> list[Defect]:
    """Excess material: connected blobs of the residual (m, m, mm) above a tenth of its peak holding
    at least ``min_drop_mm3`` with a confidence (``confidence(blob)``, blob (m, m) bool) of
    ``z_min`` at least; centre, diameter, volume and peak in mm."""
    peak = float(residual_mm.max())
    if not peak > 0.0:
        return []
    labels, count = ndimage.label(residual_mm > 0.1 * peak)
    defects = []
    m = residual_mm.shape[0]
    for label in range(1, count + 1):
        blob = labels == label
        volume = float(residual_mm[blob].sum()) * cell_mm**2
        z = confidence(blob) if volume >= tol.min_drop_mm3 else 0.0
        if z < tol.z_min:
            continue
        rows, cols = np.nonzero(blob)
        weights = residual_mm[rows, cols]
        x = (float(np.average(cols, weights=weights)) - (m - 1) / 2) * cell_mm
        y = (float(np.average(rows, weights=weights)) - (m - 1) / 2) * cell_mm
        diameter = 2.0 * np.sqrt(blob.sum() / np.pi) * cell_mm
        defects.append(Defect("excess", x, y, float(diameter), volume, float(residual_mm[blob].max()), volume,
                              evidence=z * z, confidence=z, model="residual", params=()))
    return defects


def placed_drop_defects(drops: list[Drop], tol: TrackTolerances, confidence: Callable[[int], float]) -> list[Defect]:
    """Excess material: the drops (mm) of at least ``min_drop_mm3`` with a confidence
    (``confidence(i)`` of drop i) of ``z_min`` at least; the diameter at half height."""
    defects = []
    for i, drop in enumerate(drops):
        z = confidence(i) if drop.volume() >= tol.min_drop_mm3 else 0.0
        if z < tol.z_min:
            continue
        diameter = 2.0 * drop.radius * np.sqrt(2.0 * np.log(2.0))
        defects.append(Defect("excess", drop.x, drop.y, float(diameter), drop.volume(), drop.height, drop.volume(),
                              evidence=z * z, confidence=z, model="drop", params=(drop.radius, drop.height)))
    return defects


def gap_defects(fitted: TrackSet, opened: list[tuple[int, float, float]], tol: TrackTolerances,
                confidence: Callable[[int], float]) -> list[Defect]:
    """Interruptions: the gaps the fit opened, each (track index, centre's arc length mm, length mm),
    of 2 GAP_EDGE_MM at least and a confidence (``confidence(i)`` of gap i) of ``z_min`` at least;
    placed on the fitted bead, the glass missing as its volume."""
    defects = []
    for i, (index, centre, length) in enumerate(opened):
        z = confidence(i) if length >= 2.0 * GAP_EDGE_MM else 0.0
        if z < tol.z_min:
            continue
        track = fitted.tracks[index]
        x, y = _on_bead(track, centre)
        height = float(np.interp(centre, track.knot_arcs(), track.height))
        missing = track.section_area(centre) * length
        defects.append(Defect("interruption", x, y, length, 1.0, -height, -missing, evidence=z * z,
                              confidence=z, model=f"gap:{track.name}", params=(centre, length)))
    return defects
