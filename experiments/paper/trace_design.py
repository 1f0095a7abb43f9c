"""The glass of an sfc-design run as cut: its glass.stl traced ray by ray by the independent path
tracer (operators/mesh/path_trace.py: flat facets, Snell and total reflection at every face, the
side walls included; it shares nothing with the design's model but the mesh), against the target
and against the design's own caustic (caustic.npy, the exact wavefront renderer's).

Example::

    python -m experiments.paper.trace_design outputs/design/2026-12-06/11-02-33 --rays 16777216

Writes RUN/traced.npy (flux per pixel, W, the target's pixels) and prints the matches. The tracer
bins rays, so its image carries its own noise: the two halves' difference estimates it, and the
match to the target is printed with and without it (docs/design.md, "The glass as cut").
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from experiments.apps.input_errors import run_command
from framework.core.image_metrics import relative_l2, ssim
from framework.design.design_setup import prepare_design
from operators.mesh.path_trace import trace_mesh

INPUT_ERROR_STATUS = 2
AIM_MARGIN = 1.2  # the rays aim over this times the glass's square on its bottom's top plane (covers a raised top)


def parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(prog="python -m experiments.paper.trace_design", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="directory of an sfc-design run")
    p.add_argument("--rays", type=int, default=1 << 24, help="rays in all (default 16777216)")
    p.add_argument("--seed", type=int, default=7, help="seeds the rays' aim points (default 7)")
    return p


def _file(path: Path) -> Path:
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing; pass the directory of a finished sfc-design run")
    return path


def trace_design(args: argparse.Namespace) -> dict[str, float]:
    """Trace ``args.run_dir``'s glass.stl, write traced.npy and return the figures."""
    run = args.run_dir
    if args.rays < 2:
        raise ValueError(f"--rays={args.rays} must be at least 2 (two halves estimate the noise)")
    cfg = OmegaConf.to_container(OmegaConf.load(_file(run / ".hydra" / "config.yaml")), resolve=True)
    target = np.load(_file(run / "target.npy"))[0].astype(np.float64)
    caustic = np.load(_file(run / "caustic.npy"))[0].astype(np.float64)
    setup = prepare_design(cfg, base_dir=run)
    scene, mm = setup.scene, setup.mm
    halves = [trace_mesh(_file(run / "glass.stl"), tuple(v * mm for v in scene.light.position), scene.indices[0],
                         AIM_MARGIN * scene.substrate.half_width * mm, scene.substrate.thickness * mm,
                         scene.receiver.z * mm, scene.receiver.half_width * mm, target.shape[0],
                         max(args.rays // 8, 1), seed=args.seed + k, batches=4) for k in range(2)]
    traced = 0.5 * (halves[0].image + halves[1].image)  # each half a whole image from its own rays
    np.save(run / "traced.npy", traced)
    noise = relative_l2(halves[0].image, halves[1].image) / 2.0  # of their mean: ||a - b|| / ||a + b||
    match = relative_l2(traced, target)
    return {"relative_l2": match, "ssim": ssim(traced, target), "noise": noise,
            "relative_l2_noise_removed": math.sqrt(max(match ** 2 - noise ** 2, 0.0)),
            "from_caustic": relative_l2(traced, caustic),
            "wall_share": 0.5 * sum(h.wall_flux for h in halves) / max(float(traced.sum()), 1e-300)}


def report(args: argparse.Namespace) -> None:
    """Trace ``args.run_dir``'s glass (:func:`trace_design`) and print the figures."""
    figures = trace_design(args)
    print(f"glass.stl traced ray by ray ({args.rays} rays; their own noise {figures['noise']:.1%}): matches the "
          f"target to {figures['relative_l2']:.1%} ({figures['relative_l2_noise_removed']:.1%} without that noise), "
          f"SSIM {figures['ssim']:.2f}; {figures['from_caustic']:.1%} from the design's caustic.npy; the side walls "
          f"sent {figures['wall_share']:.1%} of its light; wrote {args.run_dir / 'traced.npy'}")


def main(argv: Sequence[str] | None = None) -> None:
    """Console entry point: an input error ends in one line and exit status 2."""
    run_command(report, parser().parse_args(argv), INPUT_ERROR_STATUS)


if __name__ == "__main__":
    main()
