"""The defect report's files and sentences: defects.json / defects.csv (one row per defect),
defects.png (the deviation with the design's outline, the defects outlined and numbered, the table
beside it) and the ``verdict:`` lines."""

from __future__ import annotations

import csv
import json
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any

import numpy as np

from framework.defects.fit import Defect

__all__ = ["describe", "defect_lines", "kind_counts", "save_defect_table", "save_defect_figure"]

NAMES = {"interruption": "interruption", "too_low": "too low", "too_high": "too high", "excess": "excess material",
         "too_wide": "too wide", "too_narrow": "too narrow", "displaced": "displaced"}


def kind_counts(defects: list[Defect]) -> dict[str, int]:
    """``defects_count`` and ``defects_<kind>`` for each kind reported (a run's metrics)."""
    counts = {f"defects_{kind}": sum(d.kind == kind for d in defects) for kind in sorted({d.kind for d in defects})}
    return {"defects_count": len(defects), **counts}


def describe(defect: Defect) -> str:
    """One defect in words, e.g. 'interruption at (12.1, -3.4) mm, 1.5 mm long, 98% of the glass missing'."""
    where = f"{NAMES[defect.kind]} at ({defect.x_mm:.1f}, {defect.y_mm:.1f}) mm"
    if defect.kind == "interruption":
        size = f"{defect.length_mm:.1f} mm long, {100 * defect.size:.0f}% of the glass missing"
    elif defect.kind in ("too_low", "too_high"):
        size = f"{100 * abs(defect.size):.0f}% {'low' if defect.size > 0 else 'high'} over {defect.length_mm:.1f} mm"
    elif defect.kind == "excess":
        size = f"{defect.size:.2f} mm3, {defect.peak_mm:.2f} mm high"
    elif defect.kind == "displaced":
        size = f"shifted {defect.size:.2f} mm over {defect.length_mm:.1f} mm"
    else:
        size = f"{100 * abs(defect.size):.0f}% {'wider' if defect.size > 0 else 'narrower'} over " \
               f"{defect.length_mm:.1f} mm"
    return f"{where}, {size} (confidence {defect.confidence:.3f})"


def defect_lines(defects: list[Defect], min_evidence: float, within: int, tolerance: float,
                 tolerance_mm: float) -> list[str]:
    """The report in sentences: how many defects, each described, and what the rest means (``within``:
    the defects the photo needs that lie within the tolerance, a fraction of height or width and a
    shift in mm)."""
    rest = f"no other deviation from the design that the photo needs (evidence >= {min_evidence:.0f} noise variances)"
    if within:
        rest += (f"; {within} more within the tolerance ({100 * tolerance:.0f}% of height or width, "
                 f"{tolerance_mm:.2f} mm of shift)")
    if not defects:
        return [f"No defect: {rest}."]
    listed = "; ".join(f"{i}. {describe(d)}" for i, d in enumerate(defects, start=1))
    return [f"{len(defects)} defect{'s' if len(defects) > 1 else ''}: {listed}; {rest}."]


def save_defect_table(output_dir: Path, defects: list[Defect], settings: Any, metrics: dict[str, Any]) -> None:
    """defects.json (settings, counts, defects) and defects.csv (one row per defect)."""
    payload = {"settings": asdict(settings), **metrics, "defects": [d.as_dict() for d in defects]}
    (output_dir / "defects.json").write_text(json.dumps(payload, indent=2))
    with open(output_dir / "defects.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["number", *[f.name for f in fields(Defect)]])
        for i, defect in enumerate(defects, start=1):
            writer.writerow([i, *defect.as_dict().values()])


def save_defect_figure(path: Path, deviation_mm: np.ndarray, design_mm: np.ndarray, defects: list[Defect],
                       half_width_mm: float, min_evidence: float) -> Path:
    """The deviation map (diverging, mm) with the design's outline (its 10%-of-peak contour), each
    defect's box numbered, and the table of defects beside it."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    extent = (-half_width_mm, half_width_mm, -half_width_mm, half_width_mm)
    limit = max(float(np.abs(deviation_mm).max()), 1e-6)
    fig, (ax, table_ax) = plt.subplots(1, 2, figsize=(13, 6), gridspec_kw={"width_ratios": [1.0, 1.1]})
    image = ax.imshow(deviation_mm, origin="lower", extent=extent, cmap="RdBu_r", vmin=-limit, vmax=limit)
    fig.colorbar(image, ax=ax, fraction=0.046, label="reconstruction - design (mm)")
    if float(design_mm.max()) > 0:
        x = np.linspace(-half_width_mm, half_width_mm, design_mm.shape[0])
        ax.contour(x, x, design_mm, levels=[0.1 * float(design_mm.max())], colors="k", linewidths=0.7)
    for i, defect in enumerate(defects, start=1):
        side = defect.length_mm + 2.0
        ax.add_patch(Rectangle((defect.x_mm - side / 2, defect.y_mm - side / 2), side, side, fill=False,
                               edgecolor="lime", linewidth=1.5))
        ax.annotate(str(i), (defect.x_mm + side / 2, defect.y_mm + side / 2), color="lime", fontsize=11,
                    fontweight="bold")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(f"{len(defects)} defect(s) (evidence >= {min_evidence:.0f}); design outline in black")
    table_ax.axis("off")
    if defects:
        rows = [
            [
                str(i),
                NAMES[d.kind],
                f"({d.x_mm:.1f}, {d.y_mm:.1f})",
                f"{d.length_mm:.1f}",
                f"{d.size:+.2f}",
                f"{d.peak_mm:+.2f}",
                f"{d.volume_mm3:+.2f}",
                f"{d.confidence:.3f}",
            ]
            for i, d in enumerate(defects, start=1)
        ]
        table = table_ax.table(cellText=rows[:20], colLabels=["#", "kind", "at (mm)", "length mm", "size", "peak mm",
                                                              "volume mm3", "confidence"], loc="center",
                               colWidths=[0.05, 0.2, 0.17, 0.11, 0.09, 0.1, 0.13, 0.13])
        table.auto_set_font_size(False)
        table.set_fontsize(8)
        table.scale(1.0, 1.4)
    else:
        table_ax.text(0.5, 0.5, "no deviation from the design that the photo needs", ha="center", va="center")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
