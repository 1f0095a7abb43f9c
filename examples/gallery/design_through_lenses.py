"""Caustic design through optical elements: glass whose caustic, seen through the paper's two lenses
(a biconvex lens above the print, a meniscus below the substrate; conf/operator/two_lenses.yaml),
is the built-in ring target, designed by sfc-design's method in a 30 s budget; the target, the
designed heights and their caustic rendered independently.

    python -m examples.gallery.design_through_lenses --out figures
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from examples.gallery.common import command_line, config
from framework.design.design_run import run_design
from framework.design.design_setup import prepare_design

CASE = ["operator=two_lenses", "receiver.z=-1.0", "target.image=ring", "target.resolution=64",
        "height_field.resolution=64", "design_method.transport_resolution=64", "seconds=30", "previews=[]"]


def main(out: Path) -> Path:
    """Design into ``out``/design_through_lenses and write the figure; returns the PNG."""
    work = out / "design_through_lenses"
    cfg = config("design", CASE, work / "mlruns")
    setup = prepare_design(cfg)
    result = run_design(cfg, work / "run", setup=setup)
    caustic = np.load(work / "run" / "caustic.npy")
    fig = Figure(figsize=(10, 3.4), layout="constrained")
    axes = fig.subplots(1, 3)
    panels = (("target", setup.target.numpy()[0], "gray"), ("heights (scene units)", result.heights, "viridis"),
              ("its caustic, rendered independently", caustic[0], "gray"))
    for ax, (title, image, cmap) in zip(axes, panels):
        shown = ax.imshow(image, origin="lower", cmap=cmap)
        ax.set_title(title, fontsize=9)
        ax.set_axis_off()
        if cmap == "viridis":
            fig.colorbar(shown, ax=ax, shrink=0.8)
    fig.suptitle(f"through two lenses: {result.verdict[0]}"[:110], fontsize=9)
    (out / "design_through_lenses.png").parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "design_through_lenses.png", dpi=100)
    return out / "design_through_lenses.png"


if __name__ == "__main__":
    command_line(main, __doc__)
