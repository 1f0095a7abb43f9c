"""An operator of one's own: ``shadow`` (examples/plugins/shadow_operator.py), a linear stand-in for
the caustic in which each height sample lights a square of pixels, registered in this process and
used by the whole pipeline: its synthetic data, M2V1 with Morozov's rule, the figure.

    python -m examples.gallery.custom_operator --out figures
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from examples.gallery.common import config, heights_figure
from examples.plugins.shadow_operator import ShadowOperator
from framework.core.registry import available, register
from framework.reconstruction.reconstruction import run_reconstruction

CASE = ["scene=bump", "initial=zero", "height_field.resolution=32", "receiver.resolution=64", "data.delta=0.01",
        "data.reference_resolution=64"]


def main(out: Path) -> Path:
    """Run the reconstruction into ``out``/custom_operator and write its figure; returns the PNG."""
    if "shadow" not in available("operator"):
        register("operator", "shadow")(ShadowOperator)
    work = out / "custom_operator"
    cfg = config("reconstruct", CASE, work / "mlruns")
    cfg["operator"] = {"name": "shadow", "gain": 2.0}  # F(d) = 1 + 2 U d
    metrics = run_reconstruction(cfg, work / "run", work)
    truth, result = np.load(work / "run" / "ground_truth.npy"), np.load(work / "run" / "height_field.npy")
    title = (f"operator shadow, {metrics['method']}: {metrics['iterations']} iterations, discrepancy "
             f"{metrics['discrepancy_over_delta']:.2f} x the noise level, error {metrics['rel_error']:.4f}")
    return heights_figure({"truth": truth, "reconstruction": result}, out / "custom_operator.png", title)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("figures"), help="folder of the figure and the run")
    print(f"wrote {main(parser.parse_args().out)}")
