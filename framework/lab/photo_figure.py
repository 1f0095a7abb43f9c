"""The photo import's figure: the processed photo with the receiver's quadrilateral, the rectified
image and the weights (framework/lab/photo_import.py, docs/photo_import.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from framework.files.plotting import label_xy_axes, normalise, save_figure
from framework.lab.photo_import import PhotoImport

__all__ = ["save_photo_figure"]


def save_photo_figure(path: str | Path, photo_import: PhotoImport, dpi: int = 150) -> Path:
    """One PNG: the processed photo with the receiver quadrilateral and labelled corners (bad
    photo pixels in red), the rectified image (rows y-up) and the weights (0 in red)."""
    result = photo_import
    w = result.half_width
    fig = Figure(figsize=(13.0, 4.4), dpi=dpi, layout="constrained")
    ax_p, ax_i, ax_w = fig.subplots(1, 3)
    ax_p.imshow(normalise(result.photo), cmap="gray")
    if result.bad_photo_pixels.any():
        overlay = np.zeros(result.photo.shape + (4,))
        overlay[result.bad_photo_pixels] = (1.0, 0.0, 0.0, 1.0)
        ax_p.imshow(overlay)
    loop = np.vstack([result.corners, result.corners[:1]])
    ax_p.plot(loop[:, 0], loop[:, 1], color="cyan", lw=1.0)
    for (col, row), label in zip(result.corners, ("BL (-W,-W)", "BR (W,-W)", "TR (W,W)", "TL (-W,W)")):
        ax_p.plot(col, row, "o", color="cyan", ms=3)
        ax_p.annotate(label, (col, row), color="yellow", fontsize=7, xytext=(3, 3), textcoords="offset points",
                      bbox={"facecolor": "black", "alpha": 0.6, "pad": 1, "lw": 0})
    ax_p.set_title(f"photo {result.path.name} (linear)", fontsize=9)
    ax_p.set_xlabel("column (px)")
    ax_p.set_ylabel("row (px)")
    extent = (-w, w, -w, w)
    ax_i.imshow(normalise(result.image[0]), origin="lower", extent=extent, cmap="inferno")
    ax_i.set_title("rectified receiver image", fontsize=9)
    zero = result.weights[0] == 0
    ax_w.imshow(normalise(result.image[0]), origin="lower", extent=extent, cmap="gray", alpha=0.5)
    overlay = np.zeros(zero.shape + (4,))
    overlay[zero] = (1.0, 0.0, 0.0, 1.0)
    ax_w.imshow(overlay, origin="lower", extent=extent)
    ax_w.set_title(f"weights: {int(zero.sum())} receiver pixels at 0 (red)", fontsize=9)
    label_xy_axes(ax_i, ax_w)
    return save_figure(fig, path)
