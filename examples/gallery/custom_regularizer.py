"""A regulariser of one's own: the Tikhonov term alpha/2 ||d||^2 (examples/plugins/l2_regularizer.py),
registered in this process under ``l2_pixel`` and put in place of M2's L1 term; its result beside the
paper's M2V0 (L1 and bounds, no volume term) on the same data.

    python -m examples.gallery.custom_regularizer --out figures
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from examples.gallery.common import SMALL, command_line, config, heights_figure
from examples.plugins.l2_regularizer import PixelL2
from framework.core.registry import available, register
from framework.reconstruction.reconstruction import run_reconstruction

CASE = ["scene=gaussian", "experiment=m2v0", "initial=zero", *SMALL]
OWN_TERMS = {"l2_pixel": {"alpha": 1e-3}, "bounds": {"p1": 0.0, "p2": 0.3}}  # Tikhonov, then the bounds


def main(out: Path) -> Path:
    """Run both reconstructions into ``out``/custom_regularizer and write the figure; returns the PNG."""
    if "l2_pixel" not in available("regularizer"):
        register("regularizer", "l2_pixel")(PixelL2)
    work = out / "custom_regularizer"
    panels, errors = {}, {}
    for label, terms in (("M2V0 (L1 + bounds)", None), ("L2 + bounds", OWN_TERMS)):
        cfg = config("reconstruct", CASE, work / "mlruns")
        if terms is not None:
            cfg["solver"]["regularizers"] = terms
        run = work / label.split()[0]
        metrics = run_reconstruction(cfg, run, work)
        panels.setdefault("truth", np.load(run / "ground_truth.npy"))
        panels[label], errors[label] = np.load(run / "height_field.npy"), metrics["rel_error"]
    title = ", ".join(f"{label}: error {error:.3f}" for label, error in errors.items())
    return heights_figure(panels, out / "custom_regularizer.png", title)


if __name__ == "__main__":
    command_line(main, __doc__)
