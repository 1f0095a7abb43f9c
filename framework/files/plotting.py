"""Images and figures of height fields and caustics (Agg, no display needed).

Arrays follow [row, col] = [y, x] with y growing with the row index, so figures use
origin='lower' and PNG files are written with their rows flipped (+y up).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING
from collections.abc import Sequence

import numpy as np
from PIL import Image

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["normalise", "caustic_rgb", "label_xy_axes", "save_caustic_png", "save_figure",
           "save_height_and_caustic_figure"]

Extent = tuple[float, float, float, float]


def label_xy_axes(*axes, unit: str = "scene units") -> None:
    """Label the axes of plan-view panels x (unit) and y (unit)."""
    for ax in axes:
        ax.set_xlabel(f"x ({unit})")
        ax.set_ylabel(f"y ({unit})")


def save_figure(fig: Figure, path: str | Path, **savefig_options) -> Path:
    """Write ``fig`` to ``path`` (its directory created as needed); returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, **savefig_options)
    return path


def normalise(values: np.ndarray, percentile: float = 99.9) -> np.ndarray:
    """``values`` divided by their ``percentile``-th percentile and clipped to [0, 1]."""
    if not 0.0 < percentile <= 100.0:
        raise ValueError(f"percentile={percentile} must lie in (0, 100], e.g. 99.9")
    top = float(np.percentile(values, percentile)) if values.size else 0.0
    if not top > 0.0:
        top = float(values.max(initial=0.0)) or 1.0
    return np.clip(values / top, 0.0, 1.0)


def show_panel(ax, title: str, image: np.ndarray, caustic: bool, top: float) -> None:
    """One panel of a comparison figure over [-1, 1]^2: a caustic (n, n), normalised, or heights
    (m, m) on the colour scale 0 .. top (scene units); no ticks."""
    if caustic:
        ax.imshow(normalise(image), origin="lower", extent=(-1, 1, -1, 1), cmap="inferno")
    else:
        ax.imshow(image, origin="lower", extent=(-1, 1, -1, 1), cmap="viridis", vmin=0.0, vmax=top)
    ax.set_title(title, fontsize=8)
    ax.set_xticks([])
    ax.set_yticks([])


def caustic_rgb(image: np.ndarray, wavelengths: Sequence[float] | None = None,
                percentile: float = 99.9) -> np.ndarray:
    """Display image (n, n) greyscale or (n, n, 3) RGB in [0, 1] from a caustic (c, n, n).

    c = 1: greyscale; c = 3: RGB with the longest wavelength as red when ``wavelengths`` is
    given (otherwise channel order R, G, B), all channels normalised together; any other c:
    the first channel in greyscale.
    """
    image = np.asarray(image, dtype=np.float64)
    if image.ndim != 3:
        raise ValueError(f"caustic image must have shape (c, n, n), got {image.shape}")
    if image.shape[0] == 3:
        order = np.argsort(wavelengths)[::-1] if wavelengths is not None else np.arange(3)
        return normalise(np.moveaxis(image[order], 0, -1), percentile)
    return normalise(image[0], percentile)


def save_caustic_png(image: np.ndarray, path: str | Path, wavelengths: Sequence[float] | None = None,
                     percentile: float = 99.9) -> Path:
    """Write a caustic (c, n, n) as an 8-bit PNG, +y up (rows flipped); see :func:`caustic_rgb`."""
    display = caustic_rgb(image, wavelengths, percentile)[::-1]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.round(display * 255.0).astype(np.uint8)).save(path)
    return path


def save_height_and_caustic_figure(heights: np.ndarray, image: np.ndarray, path: str | Path,
                                   height_extent: Extent = (-1.0, 1.0, -1.0, 1.0),
                                   receiver_extent: Extent = (-1.0, 1.0, -1.0, 1.0),
                                   percentile: float = 99.9, dpi: int = 150,
                                   height_cmap: str = "viridis", caustic_cmap: str = "inferno") -> Path:
    """Heights (m, m) and caustic (c, n, n) side by side with colorbars, origin='lower'.

    Extents are (x_min, x_max, y_min, y_max) in scene units. Heights are shown in scene units;
    the caustic as irradiance in W per scene unit^2 (summed over channels when c > 1), its
    colour scale capped at the ``percentile``-th percentile.
    """
    heights = np.asarray(heights, dtype=np.float64)
    image = np.asarray(image, dtype=np.float64)
    if heights.ndim != 2:
        raise ValueError(f"heights must have shape (m, m), got {heights.shape}")
    if image.ndim != 3:
        raise ValueError(f"caustic image must have shape (c, n, n), got {image.shape}")
    total = image.sum(axis=0)
    vmax = float(np.percentile(total, percentile)) or float(total.max()) or 1.0
    from matplotlib.figure import Figure  # matplotlib is imported when a figure is drawn

    fig = Figure(figsize=(10.0, 4.4), dpi=dpi, layout="constrained")
    ax_h, ax_c = fig.subplots(1, 2)
    shown = ax_h.imshow(heights, origin="lower", extent=height_extent, cmap=height_cmap)
    ax_h.set_title("printed heights d")
    fig.colorbar(shown, ax=ax_h, label="height (scene units)")
    shown = ax_c.imshow(total, origin="lower", extent=receiver_extent, cmap=caustic_cmap, vmin=0.0, vmax=vmax)
    ax_c.set_title("caustic" if image.shape[0] == 1 else f"caustic (sum of {image.shape[0]} channels)")
    fig.colorbar(shown, ax=ax_c, label="irradiance (W / scene unit$^2$)")
    label_xy_axes(ax_h, ax_c)
    return save_figure(fig, path)
