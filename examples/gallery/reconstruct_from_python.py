"""A reconstruction from Python: the built-in gaussian ridge, rendered by the exact wavefront renderer
with 5% noise, recovered by M2V1 from the transport start; the truth against the result.

    python -m examples.gallery.reconstruct_from_python --out figures
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from examples.gallery.common import SMALL, config, heights_figure
from framework.reconstruction.reconstruction import run_reconstruction


def main(out: Path) -> Path:
    """Run the reconstruction into ``out``/reconstruct_from_python and write its figure; returns the PNG."""
    work = out / "reconstruct_from_python"
    cfg = config("reconstruct", ["scene=gaussian", *SMALL], work / "mlruns")
    metrics = run_reconstruction(cfg, work / "run", work)
    truth, result = np.load(work / "run" / "ground_truth.npy"), np.load(work / "run" / "height_field.npy")
    title = (f"{metrics['method']}: {metrics['iterations']} iterations, discrepancy "
             f"{metrics['discrepancy_over_delta']:.2f} x the noise level, error {metrics['rel_error']:.3f}")
    return heights_figure({"truth": truth, "reconstruction": result}, out / "reconstruct_from_python.png", title)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("figures"), help="folder of the figure and the run")
    print(f"wrote {main(parser.parse_args().out)}")
