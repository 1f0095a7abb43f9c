"""What the gallery scripts share: a small reconstruction config composed from conf/, a figure of
height fields side by side, a reconstruction drawn against its truth, and the command line."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from experiments.apps.configs import app_config
from framework.reconstruction.reconstruction import run_reconstruction

# A small problem that still runs the real operator: 64 x 64 heights and receiver pixels.
SMALL = ["receiver.resolution=64", "height_field.resolution=64", "data.reference_resolution=128"]


def config(name: str, overrides: list[str], store: Path) -> dict[str, Any]:
    """The plain config of conf/<name>.yaml with ``overrides``, logging to the MLflow store ``store``."""
    return app_config(name, [*overrides, f"tracking.store_dir={store}"])


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


def truth_against_reconstruction(cfg: dict[str, Any], work: Path, figure: Path, label: str) -> Path:
    """Run the reconstruction ``cfg`` (synthetic data) into ``work``/run and draw its result beside the
    truth, ``label`` and the run's iterations, discrepancy and error in the title; returns ``figure``."""
    metrics = run_reconstruction(cfg, work / "run", work)
    truth, result = np.load(work / "run" / "ground_truth.npy"), np.load(work / "run" / "height_field.npy")
    title = (f"{label}{metrics['method']}: {metrics['iterations']} iterations, discrepancy "
             f"{metrics['discrepancy_over_delta']:.2f} x the noise level, error {metrics['rel_error']:.4f}")
    return heights_figure({"truth": truth, "reconstruction": result}, figure, title)


def command_line(main: Callable[[Path], Path], doc: str) -> None:
    """Run a gallery script's ``main`` on the --out folder of its command line and say what it wrote."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("figures"), help="folder of the figure and the runs")
    print(f"wrote {main(parser.parse_args().out)}")
