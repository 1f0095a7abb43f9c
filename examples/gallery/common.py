"""What the gallery scripts share: a small reconstruction config composed from conf/ and a figure of
height fields side by side."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from hydra import compose, initialize_config_dir
from matplotlib.figure import Figure

import conf
from framework.scene.scene_config import to_plain

# A small problem that still runs the real operator: 64 x 64 heights and receiver pixels.
SMALL = ["receiver.resolution=64", "height_field.resolution=64", "data.reference_resolution=128"]


def config(name: str, overrides: list[str], store: Path) -> dict[str, Any]:
    """The plain config of conf/<name>.yaml with ``overrides``, logging to the MLflow store ``store``."""
    with initialize_config_dir(config_dir=conf.DIRECTORY, version_base=None):
        return to_plain(compose(name, overrides=[*overrides, f"tracking.store_dir={store}"]))


def heights_figure(panels: dict[str, np.ndarray], out: Path, title: str) -> Path:
    """Height fields (m, m), scene units, side by side on one colour scale, and their centre rows."""
    fig = Figure(figsize=(3.2 * len(panels) + 3.2, 3.2), layout="constrained")
    axes = fig.subplots(1, len(panels) + 1)
    top = max(float(p.max()) for p in panels.values())
    for ax, (label, heights) in zip(axes, panels.items()):
        shown = ax.imshow(heights, origin="lower", vmin=0.0, vmax=top, cmap="viridis")
        ax.set_title(label)
        ax.set_axis_off()
        axes[-1].plot(heights[heights.shape[0] // 2], label=label)
    fig.colorbar(shown, ax=axes[:-1], shrink=0.8, label="height (scene units)")
    axes[-1].set_title("centre row")
    axes[-1].legend(fontsize=7)
    fig.suptitle(title)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    return out
