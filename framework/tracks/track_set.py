"""A print as tracks: beads along paths with profiles along their arc length, and drops.

Everything here is in millimetres (what a printer's tool path and a lab's report use); the
representation that renders it onto the heights grid converts to scene units
(framework/tracks/track_heights.py).

A bead's cross-section at arc length s, a distance r from its centre line (moved across by the
offset o(s)), with v = 2 r / width(s) and p = 1 / shape, is the power cap

    height(s) * max(0, 1 - v^2 / c^2)^p,    c^2 = 1 / (1 - 2^(-1/p))

``width`` is the full width at half height (c puts the half height at v = 1). One shape parameter
spans the beads glass forms: shape -> 0 a Gaussian (the limit of the power), 1 a parabola (a
flat-lying melted bead), 2 an ellipse (a half cylinder), 3 flatter still, towards a flat top.
A track may instead carry its own cross-section (``section``: the design's bead as measured from
the design's heights, framework/tracks/from_design.py), height over peak sampled at
v = 0 .. SECTION_REACH; the profiles then scale and move that section, and ``shape`` is unused.
Profiles are piecewise linear between knots equally spaced along the path. An interruption is a
gap: an interval of the path (its centre's arc length and its length) where the bead is cut, its
ends sharp to GAP_EDGE_MM (a bead's melted end is round over about its height, not ramped over a
knot spacing). Drops are round Gaussian blobs.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from framework.tracks.geometry import path_length

__all__ = ["Track", "Drop", "TrackSet", "bead_area_factor", "SHAPE_RANGE", "DEFAULT_SHAPE", "SECTION_REACH",
           "SECTION_SAMPLES", "GAP_EDGE_MM"]

DEFAULT_SHAPE = 1.0  # a parabola: a bead's shape where nothing says otherwise
SECTION_REACH, SECTION_SAMPLES = 4.0, 161  # a measured section's samples over v = 2 r / width in [0, 4]
SHAPE_RANGE = (0.02, 3.0)  # the bead family: Gaussian (0) .. parabola (1) .. ellipse (2) .. flat-topped
GAP_EDGE_MM = 0.1  # a gap's ends: the logistic's scale along the path


def bead_area_factor(shape: float) -> float:
    """The cross-section's area / (height * width): c / 2 sqrt(pi) Gamma(p + 1) / Gamma(p + 3/2) with
    p = 1 / shape (1.0645 for a Gaussian, 2/3 c for a parabola)."""
    p = 1.0 / shape
    c = 1.0 / math.sqrt(-math.expm1(-math.log(2.0) / p))
    return 0.5 * c * math.sqrt(math.pi) * math.exp(math.lgamma(p + 1.0) - math.lgamma(p + 1.5))


def _profile(values: Any, knots: int, name: str) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64).reshape(-1)
    if array.size == 1:
        array = np.full(knots, float(array[0]))
    if array.size != knots or not np.all(np.isfinite(array)):
        raise ValueError(f"a track's {name} profile has {array.size} finite values; it needs one or {knots} "
                         "(one per knot)")
    return array


@dataclass(frozen=True)
class Track:
    """One bead along a path (mm).

    Attributes:
        name: How reports name it (e.g. "track 3").
        path: (k, 2) x, y of the centre line, mm.
        height: (K,) the bead's height at K knots equally spaced along the path, mm.
        width: (K,) its full width at half height, mm.
        offset: (K,) its centre's shift across the path (positive: left of the direction), mm.
        shape: The cross-section's shape in SHAPE_RANGE (module docstring).
        layers: Beads laid on top of each other along this path (their heights summed here).
        section: (SECTION_SAMPLES,) the bead's own cross-section over v in [0, SECTION_REACH]
            (1 at v = 0, 1/2 at v = 1), or None: the power cap of ``shape``.
        gaps: The interruptions, each (arc length of its centre, length), mm.
    """

    name: str
    path: np.ndarray
    height: np.ndarray
    width: np.ndarray
    offset: np.ndarray
    shape: float = DEFAULT_SHAPE
    layers: int = 1
    section: np.ndarray | None = None
    gaps: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        path = np.asarray(self.path, dtype=np.float64)
        if path.ndim != 2 or path.shape[1] != 2 or len(path) < 2 or not np.all(np.isfinite(path)):
            raise ValueError(f"{self.name}: its path must be (k >= 2, 2) finite x, y in mm")
        object.__setattr__(self, "path", path)
        knots = max(2, np.asarray(self.height).size)  # a constant profile: its two ends
        for key in ("height", "width", "offset"):
            object.__setattr__(self, key, _profile(getattr(self, key), knots, f"{self.name}'s {key}"))
        if np.any(self.height < 0.0) or np.any(self.width <= 0.0):
            raise ValueError(f"{self.name}: heights must be >= 0 mm and widths > 0 mm")
        object.__setattr__(self, "gaps", tuple((float(c), float(n)) for c, n in self.gaps))
        if any(n < 0.0 or not 0.0 <= c <= self.length for c, n in self.gaps):
            raise ValueError(f"{self.name}: a gap's centre must lie on the path (0-{self.length:.3g} mm) and its "
                             "length be >= 0 mm")
        if not SHAPE_RANGE[0] <= self.shape <= SHAPE_RANGE[1]:
            raise ValueError(f"{self.name}: shape={self.shape} lies outside {SHAPE_RANGE} "
                             "(0 Gaussian, 1 parabola, 2 ellipse)")

    @property
    def length(self) -> float:
        """The path's length, mm."""
        return path_length(self.path)

    @property
    def knots(self) -> int:
        return int(self.height.size)

    def knot_arcs(self) -> np.ndarray:
        """(K,) the knots' arc lengths, mm."""
        return np.linspace(0.0, self.length, self.knots)

    def with_knots(self, count: int) -> Track:
        """The same bead with its profiles resampled (linearly) at ``count`` knots."""
        old, new = self.knot_arcs(), np.linspace(0.0, self.length, count)
        return replace(self, height=np.interp(new, old, self.height), width=np.interp(new, old, self.width),
                       offset=np.interp(new, old, self.offset))

    def volume(self) -> float:
        """The bead's volume, mm^3 (its cross-section's area integrated along the path, less its gaps;
        round ends aside)."""
        area = self.height * self.width * self.area_factor()
        cut = sum(self.section_area(c) * n for c, n in self.gaps)
        return float(np.trapezoid(area, self.knot_arcs())) - cut

    def section_area(self, arc: float) -> float:
        """The cross-section's area (mm^2) at arc length ``arc`` (mm), linear between the knots."""
        return float(np.interp(arc, self.knot_arcs(), self.height * self.width * self.area_factor()))

    def area_factor(self) -> float:
        """The cross-section's area / (height * width)."""
        if self.section is None:
            return bead_area_factor(self.shape)
        return float(np.trapezoid(self.section, np.linspace(0.0, SECTION_REACH, SECTION_SAMPLES)))

    def as_dict(self) -> dict[str, Any]:
        return {"section": None if self.section is None else self.section.tolist(),
                "name": self.name, "path_mm": self.path.tolist(), "height_mm": self.height.tolist(),
                "width_mm": self.width.tolist(), "offset_mm": self.offset.tolist(), "shape": self.shape,
                "layers": self.layers, "gaps_mm": [list(g) for g in self.gaps]}


@dataclass(frozen=True)
class Drop:
    """A round blob of glass: centre (x, y), standard deviation ``radius`` and peak ``height``, mm."""

    x: float
    y: float
    radius: float
    height: float

    def volume(self) -> float:
        """mm^3."""
        return 2.0 * math.pi * self.radius**2 * self.height

    def as_dict(self) -> dict[str, float]:
        return {"x_mm": self.x, "y_mm": self.y, "radius_mm": self.radius, "height_mm": self.height}


@dataclass(frozen=True)
class TrackSet:
    """The tracks and drops of one print (mm)."""

    tracks: tuple[Track, ...]
    drops: tuple[Drop, ...] = field(default=())

    def __post_init__(self) -> None:
        if not self.tracks:
            raise ValueError("a track set needs one track at least")

    def with_knot_spacing(self, spacing_mm: float) -> TrackSet:
        """Every track's profiles resampled to knots about ``spacing_mm`` apart (two at least)."""
        tracks = tuple(t.with_knots(max(2, int(math.ceil(t.length / spacing_mm)) + 1)) for t in self.tracks)
        return replace(self, tracks=tracks)

    def volume(self) -> float:
        """mm^3."""
        return sum(t.volume() for t in self.tracks) + sum(d.volume() for d in self.drops)

    def save(self, path: str | Path) -> None:
        """Write the set as JSON (tracks.json)."""
        Path(path).write_text(json.dumps({"tracks": [t.as_dict() for t in self.tracks],
                                          "drops": [d.as_dict() for d in self.drops]}, indent=1))

    @classmethod
    def load(cls, path: str | Path) -> TrackSet:
        """Read :meth:`save`'s JSON."""
        raw = json.loads(Path(path).read_text())
        tracks = tuple(Track(t["name"], np.array(t["path_mm"]), np.array(t["height_mm"]), np.array(t["width_mm"]),
                             np.array(t["offset_mm"]), float(t["shape"]), int(t.get("layers", 1)),
                             None if t.get("section") is None else np.array(t["section"]),
                             tuple(tuple(g) for g in t.get("gaps_mm", [])))
                       for t in raw["tracks"])
        drops = tuple(Drop(d["x_mm"], d["y_mm"], d["radius_mm"], d["height_mm"]) for d in raw.get("drops", []))
        return cls(tracks, drops)
