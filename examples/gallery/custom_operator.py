"""An operator of one's own: ``shadow`` (examples/plugins/shadow_operator.py), a linear stand-in for
the caustic in which each height sample lights a square of pixels, registered in this process and
used by the whole pipeline: its synthetic data, M2V1 with Morozov's rule, the figure.

    python -m examples.gallery.custom_operator --out figures
"""

from __future__ import annotations

from pathlib import Path

from examples.gallery.common import command_line, config, truth_against_reconstruction
from examples.plugins.shadow_operator import ShadowOperator
from framework.core.registry import available, register

CASE = ["scene=bump", "initial=zero", "height_field.resolution=32", "receiver.resolution=64", "data.delta=0.01",
        "data.reference_resolution=64"]


def main(out: Path) -> Path:
    """Run the reconstruction into ``out``/custom_operator and write its figure; returns the PNG."""
    if "shadow" not in available("operator"):
        register("operator", "shadow")(ShadowOperator)
    work = out / "custom_operator"
    cfg = config("reconstruct", CASE, work / "mlruns")
    cfg["operator"] = {"name": "shadow", "gain": 2.0}  # F(d) = 1 + 2 U d
    return truth_against_reconstruction(cfg, work, out / "custom_operator.png", "operator shadow, ")


if __name__ == "__main__":
    command_line(main, __doc__)
