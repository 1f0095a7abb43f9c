"""A fibre print with a tool path, its design and the print with one planned defect of each kind,
for the track benchmarks (experiments/paper/reproduce_tracks.py) and the tests.

The tool path (mm, on a 50 mm substrate): beads 0.4-1 mm wide and 0.3-1.2 mm high, two that
cross a third, an arc, a diagonal and a two-layer wall. The beads are drawn as glass lies after
melting, independently of the track model's family (framework/tracks/track_set.py): a circular
segment (surface tension; at most a half cylinder, so a bead is at most 0.577 x its half-height
width high) of the nominal height and half-height width, rounded over 0.1 mm, round at its ends,
layers and crossings summed. The defects come from experiments/paper/defect_prints.py (erf-rounded ends,
drops as (1 - r^2/R^2)^(3/2) caps), placed at fixed points of the tool path.

    python -m experiments.paper.fibre_print OUT   # writes toolpath.csv, design.npy, printed.npy, planned.json
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path

import numpy as np
from scipy import ndimage

from experiments.paper.defect_prints import PlannedDefect, apply_defect

__all__ = ["TOOLPATH", "DEFECTS", "write_fibre_print", "draw_beads", "polyline_distance", "planned_defects"]

HALF_MM = 25.0  # the substrate's half width
# (name, points (x, y) mm, width mm (at half height), height mm); a repeated path is a second layer.
_ARC = [(6.0 + 9.0 * math.cos(a), 6.0 + 9.0 * math.sin(a))
        for a in np.linspace(math.radians(200), math.radians(20), 28)]
TOOLPATH: tuple[tuple[str, list[tuple[float, float]], float, float], ...] = (
    ("low_line", [(-18.0, -15.0), (16.0, -15.0)], 0.6, 0.32),
    ("thin_line", [(-18.0, -6.0), (16.0, -6.0)], 0.52, 0.3),
    ("cross_line", [(-10.0, -20.0), (-10.0, 16.0)], 0.8, 0.45),
    ("arc", _ARC, 0.7, 0.4),
    ("wall", [(-4.0, 19.0), (18.0, 19.0)], 1.0, 0.55),
    ("wall_top", [(-4.0, 19.0), (18.0, 19.0)], 1.0, 0.55),
    ("diagonal", [(8.0, -21.0), (19.0, -9.0)], 1.0, 0.57),
)
# (kind, size, length mm, a point of the tool path (x, y) mm): one defect of each kind.
DEFECTS: tuple[tuple[str, float, float, tuple[float, float]], ...] = (
    ("interruption", 1.0, 2.0, (-10.0, 6.0)),
    ("too_low", 0.4, 5.0, (4.0, -15.0)),
    ("too_high", -0.3, 5.0, (6.0 - 9.0, 6.0)),
    ("too_wide", 0.4, 6.0, (7.0, 19.0)),
    ("too_narrow", -0.3, 4.0, (16.3, -12.0)),
    ("displaced", 0.6, 6.0, (4.0, -6.0)),
    ("excess", 0.4, 0.0, (-14.0, -15.0)),
)


def polyline_distance(x: np.ndarray, y: np.ndarray, points: list[tuple[float, float]]) -> np.ndarray:
    """Distance (mm) of every grid point to the polyline."""
    out = np.full(x.shape, np.inf)
    for (x0, y0), (x1, y1) in zip(points[:-1], points[1:]):
        dx, dy = x1 - x0, y1 - y0
        t = np.clip(((x - x0) * dx + (y - y0) * dy) / (dx * dx + dy * dy), 0.0, 1.0)
        out = np.minimum(out, np.hypot(x - x0 - t * dx, y - y0 - t * dy))
    return out


def draw_beads(resolution: int, toolpath=TOOLPATH) -> np.ndarray:
    """The tool path's beads as melted glass on the (m, m) grid over [-25, 25]^2 mm, heights in mm."""
    axis = np.linspace(-HALF_MM, HALF_MM, resolution)
    x, y = np.meshgrid(axis, axis)
    cell = axis[1] - axis[0]
    heights = np.zeros_like(x)
    for name, points, width, height in toolpath:
        if height > width / math.sqrt(3.0):
            raise ValueError(f"bead {name}: {height} mm high and {width} mm wide is more than a half cylinder")
        radius = (width**2 + height**2) / (4.0 * height)  # the segment's circle: half height at width / 2
        r = polyline_distance(x, y, points)
        heights += np.clip(np.sqrt(np.clip(radius**2 - r**2, 0.0, None)) - (radius - height), 0.0, None)
    return ndimage.gaussian_filter(heights, 0.1 / cell)


def _site(design: np.ndarray, point: tuple[float, float]) -> tuple[int, int]:
    """The design's highest sample within 1 mm of a tool-path point (row, col)."""
    m = design.shape[0]
    cell = 2.0 * HALF_MM / (m - 1)
    col, row = ((p + HALF_MM) / cell for p in point)
    reach = int(math.ceil(1.0 / cell))
    r0, c0 = int(round(row)), int(round(col))
    window = design[r0 - reach:r0 + reach + 1, c0 - reach:c0 + reach + 1]
    dr, dc = np.unravel_index(int(np.argmax(window)), window.shape)
    return r0 - reach + int(dr), c0 - reach + int(dc)


def write_fibre_print(folder: Path, resolution: int = 256, mm_per_unit: float = 25.0,
                      defects=DEFECTS) -> dict[str, Path]:
    """Write toolpath.csv (mm), design.npy and printed.npy (scene units) and planned.json into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / "toolpath.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["track", "x_mm", "y_mm", "width_mm", "height_mm"])
        for name, points, width, height in TOOLPATH:
            for x, y in points:
                writer.writerow([name, f"{x:.4f}", f"{y:.4f}", width, height])
    design = draw_beads(resolution) / mm_per_unit
    cell_mm = 2.0 * HALF_MM / (resolution - 1)
    printed, planned = design.copy(), []
    for kind, size, length, point in defects:
        printed, defect = apply_defect(design, printed, _site(design, point), kind, size, length, cell_mm, mm_per_unit)
        planned.append(defect)
    np.save(folder / "design.npy", design)
    np.save(folder / "printed.npy", printed)
    (folder / "planned.json").write_text(json.dumps([d.as_dict() for d in planned], indent=1))
    return {name: folder / f"{name}" for name in ("toolpath.csv", "design.npy", "printed.npy", "planned.json")}


def planned_defects(folder: Path) -> list[PlannedDefect]:
    """planned.json's defects."""
    return [PlannedDefect(**d) for d in json.loads((folder / "planned.json").read_text())]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="folder for toolpath.csv, design.npy, printed.npy, planned.json")
    parser.add_argument("--resolution", type=int, default=256, help="height samples per side (0.2 mm at 256)")
    args = parser.parse_args(argv)
    files = write_fibre_print(args.out, args.resolution)
    print("\n".join(str(p) for p in files.values()))


if __name__ == "__main__":
    main()
