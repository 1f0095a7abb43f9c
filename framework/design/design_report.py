"""The pictures of a caustic design: the figure target | caustic | difference | heights with the
match per iteration, and the caustic at other screen distances (previews)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from framework.design.design_screen import has_elements, lit_half_width
from framework.design.design_target import screen_reach
from framework.files.plotting import label_xy_axes, save_caustic_png, save_figure

if TYPE_CHECKING:
    from framework.core.callbacks import MetricsHistory

__all__ = ["save_previews", "save_design_figure"]


def save_previews(setup: Any, heights: np.ndarray, photons: int, output_dir: Path) -> dict[str, float]:
    """Render the design's caustic on screens at each preview factor (``setup.settings.previews``)
    times the design distance, with seed + 2000 (the run's seed),
    each over the square the glass can light there (the screen reach under the slope limit; through
    optical elements the square the design's light covers there), by
    the operator's independent renderer; writes preview_<f>x.npy/.png. ``setup`` is the run's
    :class:`framework.design.design_setup.DesignSetup`. A screen at or above the lowest optical
    element is skipped, with a note in ``setup.notes``. Returns the power on each screen over flat
    glass's on it (``preview_<f>x_power_share``)."""
    out: dict[str, float] = {}
    distance = -setup.scene.receiver.z
    lowest = min((e.z_range[0] for e in setup.operator.elements), default=np.inf)
    seed = setup.settings.seed + 2000
    for factor in setup.settings.previews:
        if -factor * distance >= lowest:
            setup.notes.append(f"no preview at {factor:g}x: that screen (z={-factor * distance:.4g}) would lie at or "
                               f"above the lowest optical element (z={lowest:.4g})")
            continue
        receiver = replace(setup.scene.receiver, z=-factor * distance)
        scene = replace(setup.scene, receiver=receiver)
        half = (lit_half_width(setup.operator_for, scene, heights, seed) if has_elements(setup.operator)
                else screen_reach(scene, setup.constraints.max_slope))
        scene = replace(scene, receiver=replace(receiver, half_width=half))
        renderer = setup.operator_for(scene).exact_variant(photons, seed, receiver.resolution)
        image = renderer.render(torch.from_numpy(heights)).detach().double().cpu().numpy()
        flat = renderer.render(torch.zeros_like(torch.from_numpy(heights))).detach().double().cpu().numpy()
        label = f"{factor:g}x"
        np.save(output_dir / f"preview_{label}.npy", image.astype(np.float32))
        save_caustic_png(image, output_dir / f"preview_{label}.png", scene.wavelengths)
        out[f"preview_{label}_power_share"] = float(image.sum() / max(flat.sum(), 1e-300))
    return out


def save_design_figure(path: Path, setup: Any, heights: np.ndarray, caustic: np.ndarray,
                       metrics: Mapping[str, float], history: MetricsHistory) -> Path:
    """Target | designed caustic | difference | heights (mm), and the relative discrepancy per
    iteration below; ``setup`` is the run's :class:`framework.design.design_setup.DesignSetup`."""
    from matplotlib.figure import Figure

    target = setup.target.numpy().sum(axis=0)
    image = caustic.sum(axis=0) * float(target.sum()) / max(float(caustic.sum()), 1e-300)
    half, w = setup.scene.receiver.half_width * setup.mm, setup.grid.half_width * setup.mm
    screen = (-half, half, -half, half)
    fig = Figure(figsize=(13.0, 6.4), dpi=110, layout="constrained")
    grid = fig.add_gridspec(2, 4, height_ratios=[3.0, 1.2])
    axes = [fig.add_subplot(grid[0, k]) for k in range(4)]
    top = float(np.percentile(target, 99.9)) or 1.0
    axes[0].imshow(np.clip(target / top, 0, 1), origin="lower", extent=screen, cmap="gray")
    axes[0].set_title("target")
    axes[1].imshow(np.clip(image / top, 0, 1), origin="lower", extent=screen, cmap="gray")
    axes[1].set_title(f"caustic: rel. L2 {metrics['relative_l2']:.3f}, SSIM {metrics['ssim']:.2f}")
    diff = (image - target) / top
    shown = axes[2].imshow(diff, origin="lower", extent=screen, cmap="RdBu_r", vmin=-0.5, vmax=0.5)
    axes[2].set_title("caustic - target")
    fig.colorbar(shown, ax=axes[2], shrink=0.8, label="of the target's peak")
    shown = axes[3].imshow(heights * setup.mm, origin="lower", extent=(-w, w, -w, w), cmap="viridis")
    axes[3].set_title("heights")
    fig.colorbar(shown, ax=axes[3], shrink=0.8, label="mm")
    label_xy_axes(*axes, unit="mm")
    curve = fig.add_subplot(grid[1, :])
    values = history.columns().get("rel_discrepancy", [])
    curve.semilogy(np.arange(1, len(values) + 1), values, "k-")
    curve.set_xlabel("iteration")
    curve.set_ylabel("rel. discrepancy (model)")
    curve.grid(True, alpha=0.3)
    return save_figure(fig, path)
