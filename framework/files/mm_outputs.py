"""Outputs of a reconstruction in millimetres: the heights, the glass as a triangle mesh for CAD,
and the deviation from the design (docs/export.md).

Heights d (m, m) are in scene units, sampled at linspace(-W, W, m) in x (columns) and y (rows),
[row, col] = [y, x]; the glass fills [-W, W]^2 in x, y from z = 0 to z = h + d(x, y)
(operators/scene.py). One scene unit is ``mm_per_unit`` mm (framework/core/units.py).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PIL import Image, PngImagePlugin

from framework.files.plotting import label_xy_axes, save_figure
from operators.heightfield.catmull_rom import refined_surface
from operators.values import checked_number, checked_whole

if TYPE_CHECKING:
    import trimesh

__all__ = ["MESH_FORMATS", "PNG_KEYS", "PRINTED", "GlassFrame", "glass_mesh", "write_height_png", "read_height_png",
           "deviation_report", "save_deviation_figure", "export_outputs"]

MESH_FORMATS = ("stl", "obj", "ply")
PNG_KEYS = ("mm_per_count", "offset_mm", "pixel_pitch_mm")  # text metadata of height_field_mm.png
PRINTED = 1e-3  # scene units: a sample at least this high counts as printed (framework/core/masks.py's rule)
_FULL_COUNT = 65535  # 16-bit grey


@dataclass(frozen=True)
class GlassFrame:
    """The lengths the heights are exported in, checked once: the grid's half width W and the
    substrate's thickness h (scene units), and ``mm_per_unit`` (mm per scene unit)."""

    half_width: float
    thickness: float
    mm_per_unit: float

    @classmethod
    def checked(cls, half_width: float, mm_per_unit: float, thickness: float = 0.0) -> GlassFrame:
        """The frame of these values, or a ValueError naming the first bad one."""
        return cls(checked_number(half_width, "half_width", above=0.0, unit="scene units"),
                   checked_number(thickness, "thickness", unit="scene units"),
                   checked_number(mm_per_unit, "mm_per_unit", above=0.0,
                                  must="must be a length > 0 in mm per scene unit", example="25"))

    def pitch_mm(self, m: int) -> float:
        """The sample pitch (mm) of an (m, m) grid over [-W, W]^2."""
        return 2.0 * self.half_width / (m - 1) * self.mm_per_unit


def _heights(d: np.ndarray, name: str) -> np.ndarray:
    """``d`` as float64 (m, m) with m >= 2 and finite values, else a ValueError naming the value."""
    d = np.asarray(d, dtype=np.float64)
    if d.ndim != 2 or d.shape[0] != d.shape[1] or d.shape[0] < 2:
        raise ValueError(f"{name} has shape {d.shape}; heights must be a square (m, m) array with m >= 2")
    bad = np.argwhere(~np.isfinite(d))
    if bad.size:
        i, j = bad[0]
        raise ValueError(f"{name}[{i}, {j}]={d[i, j]} is not finite; replace NaN/inf heights (e.g. by 0)")
    return d


def glass_mesh(d: np.ndarray, half_width: float, thickness: float, mm_per_unit: float,
               refine: int = 1) -> trimesh.Trimesh:
    """The printed glass (substrate + print) as a closed, outward-facing triangle mesh in mm.

    Top: the operators' surface (operators/heightfield/catmull_rom.py) at ``refine`` points per
    cell along each axis (1: the samples themselves) at z = h + d, and one vertex per fine cell's
    centre, four triangles per fine cell. With refine 1 the centre is the mean of the cell's four
    corners, so the top integrates like the trapezoid rule and the volume is (2 W)^2 h + the
    trapezoid integral of d (times mm_per_unit^3), to rounding; with refine > 1 it is the surface
    at the centre, and each fine cell holds its area times (corners' sum / 6 + centre / 3).
    Bottom: the plane z = 0 as a fan from (0, 0, 0). Walls: two vertical triangles per boundary
    segment.

    Args:
        d: Heights (m, m), m >= 2, scene units; h + d > 0 everywhere.
        half_width: W, scene units. thickness: h, scene units. mm_per_unit: mm per scene unit.
        refine: Points per cell of the samples' grid, >= 1: the facets' pitch is the grid's over
            ``refine`` (finer facets cast less of their pattern on a far screen).
    """
    d = _heights(d, "d")
    frame = GlassFrame.checked(half_width, mm_per_unit, thickness)
    return _glass_mesh(*refined_surface(d, _checked_refine(refine)), frame)


def _checked_refine(refine: int) -> int:
    """The mesh's points per cell of the heights' grid, an integer >= 1."""
    return checked_whole(refine, "refine", 1, must="must be an integer >= 1 (points per cell of the heights' grid)")


def _glass_mesh(d: np.ndarray, centres: np.ndarray | None, frame: GlassFrame) -> trimesh.Trimesh:
    """:func:`glass_mesh` of checked heights on the facets' grid (k (m - 1) + 1 square) and the
    surface at those cells' centres (None: the mean of each cell's corners) in ``frame``."""
    w, base = frame.half_width, frame.thickness
    top = base + d
    if top.min() <= 0.0:
        i, j = np.unravel_index(np.argmin(top), top.shape)
        raise ValueError(f"glass top h + d = {top[i, j]:.6g} <= 0 at d[{i}, {j}]={d[i, j]:.6g} "
                         f"(thickness={base}): the print would cut through the substrate bottom; heights "
                         "must satisfy d > -thickness")
    m = d.shape[0]
    s = np.linspace(-w, w, m)
    mid = (s[:-1] + s[1:]) / 2.0
    x, y = np.meshgrid(s, s)  # [row, col] = [y, x]
    cx, cy = np.meshgrid(mid, mid)
    cz = ((top[:-1, :-1] + top[:-1, 1:] + top[1:, 1:] + top[1:, :-1]) / 4.0 if centres is None
          else base + centres)
    index = np.arange(m * m).reshape(m, m)
    # Each cell's corners counter-clockwise seen from above (+x right, +y up), and its centre vertex.
    ring = np.stack([index[:-1, :-1], index[:-1, 1:], index[1:, 1:], index[1:, :-1]], axis=-1).reshape(-1, 4)
    centre = np.broadcast_to((m * m + np.arange(ring.shape[0]))[:, None], ring.shape)
    top_faces = np.stack([centre, ring, np.roll(ring, -1, axis=1)], axis=-1).reshape(-1, 3)
    # The boundary samples counter-clockwise from (-W, -W); under each a bottom vertex at z = 0.
    loop = np.concatenate([index[0, :-1], index[:-1, -1], index[-1, :0:-1], index[:0:-1, 0]])
    first_bottom = m * m + ring.shape[0]
    bottom = first_bottom + np.arange(loop.size)
    floor_centre = first_bottom + loop.size
    t0, t1, b0, b1 = loop, np.roll(loop, -1), bottom, np.roll(bottom, -1)
    faces = np.concatenate([top_faces, np.stack([b0, b1, t1], axis=-1), np.stack([b0, t1, t0], axis=-1),
                            np.stack([np.full_like(b0, floor_centre), b1, b0], axis=-1)])
    corners = np.stack([x, y, top], axis=-1).reshape(-1, 3)
    vertices = np.concatenate([corners, np.stack([cx, cy, cz], axis=-1).reshape(-1, 3),
                               corners[loop] * np.array([1.0, 1.0, 0.0]), np.zeros((1, 3))])
    import trimesh  # imported when a mesh is written (about 1 s), not before the run starts

    return trimesh.Trimesh(vertices=vertices * frame.mm_per_unit, faces=faces, process=False)


def write_height_png(path: str | Path, d_mm: np.ndarray, pitch_mm: float) -> Path:
    """Write heights (m, m) in mm as a 16-bit grey PNG, top row = +y (rows flipped).

    Grey count c stands for offset_mm + c * mm_per_count mm, offset_mm = min(0, min d_mm), full
    white = max d_mm; the PNG text keys ``PNG_KEYS`` hold both and the sample pitch in mm.
    """
    pitch = checked_number(pitch_mm, "pitch_mm", above=0.0, unit="mm")
    return _write_height_png(Path(path), _heights(d_mm, "d_mm"), pitch)


def _write_height_png(path: Path, d_mm: np.ndarray, pitch: float) -> Path:
    """:func:`write_height_png` of checked heights (mm) and pitch (mm)."""
    offset = min(float(d_mm.min()), 0.0)
    span = float(d_mm.max()) - offset
    step = span / _FULL_COUNT if span > 0.0 else 1.0
    counts = np.round((d_mm - offset) / step).astype(np.uint16)
    info = PngImagePlugin.PngInfo()
    for key, value in zip(PNG_KEYS, (step, offset, pitch)):
        info.add_text(key, repr(value))
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.ascontiguousarray(counts[::-1])).save(path, pnginfo=info)
    return path


def read_height_png(path: str | Path) -> np.ndarray:
    """Heights (m, m) in mm, float64, from a PNG of :func:`write_height_png` (within half a count)."""
    with Image.open(path) as img:
        text = dict(getattr(img, "text", {}))
        counts = np.asarray(img).astype(np.float64)
    missing = [key for key in PNG_KEYS[:2] if key not in text]
    if missing or counts.ndim != 2:
        what = f"has no PNG text key {missing[0]!r}" if missing else f"is not greyscale (shape {counts.shape})"
        raise ValueError(f"{path} {what}; read height PNGs written by write_height_png (framework/files/mm_outputs.py)")
    return float(text["offset_mm"]) + counts[::-1] * float(text["mm_per_count"])


def deviation_report(d: np.ndarray, design: np.ndarray, grid_half_width: float,
                     mm_per_unit: float) -> dict[str, float | None]:
    """Deviation e = (d - design) * mm_per_unit (mm) of a reconstruction from its design.

    Args:
        d, design: Heights (m, m), scene units, on the same grid. grid_half_width: W, scene units.
        mm_per_unit: mm per scene unit.

    Returns:
        max_abs_mm: max |e|; mean_mm: mean e (signed, > 0: more glass than planned); rms_mm: RMS
        of e over the grid; rms_printed_mm: RMS of e over the printed area, where |d| or |design|
        is at least ``PRINTED`` (0 if empty); printed_fraction: that area's share of the grid;
        printed_volume_mm3 / planned_volume_mm3: sum(d) a and sum(design) a, a = (2 W / (m - 1))^2
        the cell area (framework/core/problem.py), in mm^3; volume_ratio: their ratio (None when
        nothing is planned).
    """
    frame = GlassFrame.checked(grid_half_width, mm_per_unit)
    return _deviation_report(*_pair(d, design), frame)


def _pair(d: np.ndarray, design: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The heights and their design, checked (:func:`_heights`) and of one shape."""
    d, design = _heights(d, "d"), _heights(design, "design")
    if design.shape != d.shape:
        raise ValueError(f"design has shape {design.shape}, the reconstruction {d.shape}; resample the design "
                         "to the reconstruction's grid")
    return d, design


def _deviation_report(d: np.ndarray, design: np.ndarray, frame: GlassFrame) -> dict[str, float | None]:
    """:func:`deviation_report` of checked heights in ``frame``."""
    scale = frame.mm_per_unit
    spacing = 2.0 * frame.half_width / (d.shape[0] - 1)
    cell_mm3 = spacing ** 2 * scale ** 3
    error = (d - design) * scale
    printed = (np.abs(d) >= PRINTED) | (np.abs(design) >= PRINTED)
    printed_volume, planned_volume = float(d.sum()) * cell_mm3, float(design.sum()) * cell_mm3
    return {
        "max_abs_mm": float(np.abs(error).max()),
        "mean_mm": float(error.mean()),
        "rms_mm": float(np.sqrt(np.mean(error ** 2))),
        "rms_printed_mm": float(np.sqrt(np.mean(error[printed] ** 2))) if printed.any() else 0.0,
        "printed_fraction": float(printed.mean()),
        "printed_volume_mm3": printed_volume,
        "planned_volume_mm3": planned_volume,
        "volume_ratio": printed_volume / planned_volume if planned_volume != 0.0 else None,
    }


def save_deviation_figure(path: str | Path, d: np.ndarray, design: np.ndarray, half_width: float,
                          mm_per_unit: float) -> Path:
    """Write the design and the reconstruction (mm), their deviation d - design (um, diverging
    colours centred at 0) and both along the centre row m // 2: heights (m, m) in scene units."""
    frame = GlassFrame.checked(half_width, mm_per_unit)
    return _save_deviation_figure(Path(path), *_pair(d, design), frame)


def _save_deviation_figure(path: Path, d: np.ndarray, design: np.ndarray, frame: GlassFrame) -> Path:
    """:func:`save_deviation_figure` of checked heights in ``frame``."""
    design_mm, d_mm = design * frame.mm_per_unit, d * frame.mm_per_unit
    error_um = (d_mm - design_mm) * 1e3
    w_mm = frame.half_width * frame.mm_per_unit
    extent = (-w_mm, w_mm, -w_mm, w_mm)
    low = min(float(design_mm.min()), float(d_mm.min()), 0.0)
    high = max(float(design_mm.max()), float(d_mm.max()), low + 1e-9)
    limit = float(np.abs(error_um).max()) or 1.0
    from matplotlib.figure import Figure  # matplotlib is imported when a figure is drawn

    # Fixed margins: a constrained layout lays the labels of the four panels out several times
    # (1.3 s against 0.7 s a figure on 2 cores, in every run with a design).
    fig = Figure(figsize=(19.0, 4.2))
    fig.subplots_adjust(left=0.04, right=0.985, bottom=0.13, top=0.9, wspace=0.35)
    axes = fig.subplots(1, 4)
    for ax, (title, field) in zip(axes, (("design", design_mm), ("reconstruction", d_mm))):
        shown = ax.imshow(field, origin="lower", extent=extent, cmap="viridis", vmin=low, vmax=high)
        ax.set_title(f"{title} d (mm)")
        fig.colorbar(shown, ax=ax, label="height (mm)")
    shown = axes[2].imshow(error_um, origin="lower", extent=extent, cmap="RdBu_r", vmin=-limit, vmax=limit)
    axes[2].set_title("deviation: reconstruction - design")
    fig.colorbar(shown, ax=axes[2], label="deviation (µm)")
    label_xy_axes(*axes[:3], unit="mm")
    m = d_mm.shape[0]
    x = np.linspace(-w_mm, w_mm, m)
    axes[3].plot(x, design_mm[m // 2], "k-", label="design")
    axes[3].plot(x, d_mm[m // 2], "r-", label="reconstruction")
    axes[3].set_title(f"centre slice y = {x[m // 2]:.3g} mm")
    axes[3].set_xlabel("x (mm)")
    axes[3].set_ylabel("height (mm)")
    axes[3].legend()
    return save_figure(fig, path, dpi=120)


def export_outputs(out_dir: str | Path, d: np.ndarray, half_width: float, thickness: float, mm_per_unit: float,
                   design: np.ndarray | None = None, formats: Sequence[str] = ("stl",), refine: int = 1
                   ) -> dict[str, Any]:
    """Write the mm outputs of heights d (m, m, scene units) into ``out_dir``.

    Files: height_field_mm.npy (float64, mm), height_field_mm.png (16-bit, :func:`write_height_png`),
    glass.<format> per format of ``MESH_FORMATS`` (:func:`glass_mesh`, ``refine`` points per cell)
    and, with a ``design`` (m, m,
    scene units), deviation.json (:func:`deviation_report`) and deviation.png.

    Returns:
        {"deviation": the deviation metrics ({} without a design), "files": the paths written}.
    """
    formats = (formats,) if isinstance(formats, str) else tuple(dict.fromkeys(formats))
    unknown = [f for f in formats if f not in MESH_FORMATS]
    if unknown:
        raise ValueError(f"unknown mesh format {unknown[0]!r}; use one or more of {', '.join(MESH_FORMATS)}")
    d = _heights(d, "d")
    if design is not None:
        d, design = _pair(d, design)
    frame = GlassFrame.checked(half_width, mm_per_unit, thickness)
    mesh = _glass_mesh(*refined_surface(d, _checked_refine(refine)), frame)
    report = {} if design is None else _deviation_report(d, design, frame)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    d_mm = d * frame.mm_per_unit
    np.save(out / "height_field_mm.npy", d_mm)
    files = [out / "height_field_mm.npy",
             _write_height_png(out / "height_field_mm.png", d_mm, frame.pitch_mm(d.shape[0]))]
    for fmt in formats:
        mesh.export(out / f"glass.{fmt}")
        files.append(out / f"glass.{fmt}")
    if design is not None:
        (out / "deviation.json").write_text(json.dumps(report, indent=2))
        files += [out / "deviation.json", _save_deviation_figure(out / "deviation.png", d, design, frame)]
    return {"deviation": report, "files": files}
