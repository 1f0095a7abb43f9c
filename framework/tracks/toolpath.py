"""A print's tracks from its tool path: a CSV of polylines or the printer's G-code (mm).

CSV: a header row and the columns ``track, x_mm, y_mm, width_mm, height_mm`` (any order; more
columns are ignored): the rows of one track, in order along it, share its ``track`` label; width
and height are the bead's nominal full width at half height and height at that point.

G-code: ``G0``/``G1`` moves in absolute or relative positioning (``G90``/``G91``, ``M82``/``M83``
for the extruder, ``G92`` resets); a track is a run of moves that extrude (E grows) in one layer
(one Z); a travel move, a retraction or a change of Z ends it. Each move's bead width and height
come from the slicer's ``;WIDTH:`` and ``;HEIGHT:`` comments where present (PrusaSlicer writes
them), else from the fibre fed per mm of path (``fibre_diameter_mm``: the bead's cross-section is
pi D^2 / 4 * dE / dl, its width that area over the height and the default bead's area factor,
framework/tracks/track_set.py), else from the given defaults.

Beads laid on each other along one path (a wall of several layers) become one track whose height
is their sum (``layers`` counts them): only their total reaches the photo.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np

from framework.tracks.geometry import resampled_path
from framework.tracks.track_set import DEFAULT_SHAPE, Track, TrackSet, bead_area_factor

__all__ = ["read_toolpath", "read_csv_toolpath", "read_gcode", "merge_layers"]

CSV_COLUMNS = ("track", "x_mm", "y_mm", "width_mm", "height_mm")
STACKED_MM = 0.1  # two paths closer than this everywhere are one path (the layers of a wall)


def _track(name: str, points: list[tuple[float, float, float, float]]) -> Track:
    """A track from per-point (x, y, width, height), its profiles at the points' arc lengths."""
    array = np.asarray(points, dtype=np.float64)
    path = array[:, :2]
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
    knots = np.linspace(0.0, arc[-1], max(2, len(points)))
    return Track(name, path, np.interp(knots, arc, array[:, 3]), np.interp(knots, arc, array[:, 2]),
                 np.zeros(knots.size))


def read_csv_toolpath(path: str | Path) -> TrackSet:
    """The tracks of a tool-path CSV (module docstring)."""
    rows: dict[str, list[tuple[float, float, float, float]]] = {}
    with open(path, newline="") as handle:
        reader = csv.DictReader(handle)
        missing = [c for c in CSV_COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise ValueError(f"tool path {path}: columns {', '.join(missing)} are missing; it needs a header row with "
                             f"{', '.join(CSV_COLUMNS)}")
        for number, row in enumerate(reader, start=2):
            try:
                values = tuple(float(row[c]) for c in CSV_COLUMNS[1:])
            except (TypeError, ValueError):
                raise ValueError(f"tool path {path}, line {number}: x_mm, y_mm, width_mm and height_mm must be "
                                 f"numbers, got {[row[c] for c in CSV_COLUMNS[1:]]}") from None
            rows.setdefault(str(row["track"]), []).append(values)  # type: ignore[arg-type]
    short = [name for name, points in rows.items() if len(points) < 2]
    if not rows or short:
        raise ValueError(f"tool path {path}: every track needs two points at least ({', '.join(short) or 'no rows'})")
    return merge_layers(TrackSet(tuple(_track(f"track {name}", points) for name, points in rows.items())))


_WORD = re.compile(r"([GMXYZEF])\s*([-+]?\d*\.?\d+(?:[eE][-+]?\d+)?)")


def read_gcode(path: str | Path, width_mm: float | None = None, height_mm: float | None = None,
               fibre_diameter_mm: float | None = None) -> TrackSet:
    """The tracks of a G-code file (module docstring); ``width_mm``/``height_mm``: a bead's nominal
    size where the file's comments and the fibre fed do not give it."""
    absolute, absolute_e = True, True
    x = y = z = e = 0.0
    width, height = width_mm, height_mm
    tracks: list[Track] = []
    current: list[tuple[float, float, float, float]] = []

    def close() -> None:
        if len(current) >= 2:
            tracks.append(_track(f"track {len(tracks) + 1}", current))
        current.clear()

    for number, raw in enumerate(Path(path).read_text().splitlines(), start=1):
        code, _, comment = raw.partition(";")
        comment = comment.strip().upper()
        if comment.startswith("WIDTH:"):
            width = float(comment[6:])
        elif comment.startswith("HEIGHT:"):
            height = float(comment[7:])
        words = {k: float(v) for k, v in _WORD.findall(code.upper())}
        command = ("G" if "G" in words else "M" if "M" in words else "") + str(int(words.get("G", words.get("M", -1))))
        if command in ("G90", "G91"):
            absolute = command == "G90"
            absolute_e = absolute
        elif command in ("M82", "M83"):
            absolute_e = command == "M82"
        elif command == "G92":
            e = words.get("E", e)
        elif command in ("G0", "G1"):
            nx = words.get("X", x if absolute else 0.0) + (0.0 if absolute else x)
            ny = words.get("Y", y if absolute else 0.0) + (0.0 if absolute else y)
            nz = words.get("Z", z if absolute else 0.0) + (0.0 if absolute else z)
            fed = (words["E"] - e if absolute_e else words["E"]) if "E" in words else 0.0
            step = math.hypot(nx - x, ny - y)
            if nz != z or fed <= 0.0 or step == 0.0:
                close()
            else:
                bead_height = height
                bead_width = width
                if fibre_diameter_mm and bead_height:
                    area = math.pi * fibre_diameter_mm**2 / 4.0 * fed / step
                    bead_width = area / (bead_height * bead_area_factor(DEFAULT_SHAPE))
                if not bead_width or not bead_height:
                    raise ValueError(f"G-code {path}, line {number}: no bead width and height known; give "
                                     "width_mm and height_mm (or fibre_diameter_mm with height_mm)")
                if not current:
                    current.append((x, y, bead_width, bead_height))
                current.append((nx, ny, bead_width, bead_height))
            x, y, z = nx, ny, nz
            if "E" in words:
                e = words["E"] if absolute_e else e + words["E"]
    close()
    if not tracks:
        raise ValueError(f"G-code {path} extrudes along no path (no G1 move with growing E in the XY plane)")
    return merge_layers(TrackSet(tuple(tracks)))


def read_toolpath(path: str | Path, width_mm: float | None = None, height_mm: float | None = None,
                  fibre_diameter_mm: float | None = None) -> TrackSet:
    """A .csv or .gcode/.gco/.nc tool path's tracks."""
    suffix = Path(path).suffix.lower()
    if not Path(path).is_file():
        raise ValueError(f"tool path {path} does not exist; give a .csv or .gcode file")
    if suffix == ".csv":
        return read_csv_toolpath(path)
    if suffix in (".gcode", ".gco", ".nc", ".g"):
        return read_gcode(path, width_mm, height_mm, fibre_diameter_mm)
    raise ValueError(f"tool path {path}: unknown format {suffix!r}; give a .csv (track, x_mm, y_mm, width_mm, "
                     "height_mm) or a .gcode file")


def _stacked(a: Track, b: Track) -> bool:
    """Whether b runs along a's path (either way) within STACKED_MM everywhere."""
    if abs(a.length - b.length) > 2 * STACKED_MM:
        return False
    pa = resampled_path(a.path, 0.5)
    pb = resampled_path(b.path, 0.5)
    if len(pa) != len(pb):
        return False
    return bool(min(np.max(np.hypot(*(pa - pb).T)), np.max(np.hypot(*(pa - pb[::-1]).T))) <= STACKED_MM)


def merge_layers(tracks: TrackSet) -> TrackSet:
    """Tracks along one path merged into one whose height is their sum and whose width is the widest."""
    merged: list[Track] = []
    for track in tracks.tracks:
        base = next((i for i, t in enumerate(merged) if _stacked(t, track)), None)
        if base is None:
            merged.append(track)
            continue
        below = merged[base]
        on = track.with_knots(below.knots)
        if np.dot(on.path[-1] - on.path[0], below.path[-1] - below.path[0]) < 0:  # laid the other way
            on = replace(on, height=on.height[::-1].copy(), width=on.width[::-1].copy())
        merged[base] = replace(below, height=below.height + on.height, width=np.maximum(below.width, on.width),
                               layers=below.layers + track.layers)
    return replace(tracks, tracks=tuple(merged))
