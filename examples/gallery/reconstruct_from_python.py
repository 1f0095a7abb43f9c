"""A reconstruction from Python: the built-in gaussian ridge, rendered by the exact wavefront renderer
with 5% noise, recovered by M2V1 from the transport start; the truth against the result.

    python -m examples.gallery.reconstruct_from_python --out figures
"""

from __future__ import annotations

from pathlib import Path

from examples.gallery.common import SMALL, command_line, config, truth_against_reconstruction


def main(out: Path) -> Path:
    """Run the reconstruction into ``out``/reconstruct_from_python and write its figure; returns the PNG."""
    work = out / "reconstruct_from_python"
    cfg = config("reconstruct", ["scene=gaussian", *SMALL], work / "mlruns")
    return truth_against_reconstruction(cfg, work, out / "reconstruct_from_python.png", "")


if __name__ == "__main__":
    command_line(main, __doc__)
