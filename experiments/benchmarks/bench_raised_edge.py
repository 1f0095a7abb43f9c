"""Glass raised at its edge, cast by the model and traced as a mesh: a ramp rising to 5 mm at one
edge and a spherical cap cut by the square, at the paper's screen (1.25 mm) and a design's (100 mm).

For each, the glass (its top the model's surface sampled ``--refine`` times per spacing) is traced
ray by ray by operators/mesh/path_trace.py in two halves (their difference gives the tracer's own
noise), and the height-field operator (substrate.edge_height covering the top, and 0: the rim left
dark) and the exact wavefront renderer are compared with it over the whole receiver. Prints one
row per case (docs/method.md, "Glass raised at its edge").

    python -m experiments.benchmarks.bench_raised_edge            # about 3 min on 2 cores
    python -m experiments.benchmarks.bench_raised_edge --heights RUN/height_field.npy --refine 2 --pixels 64

``--heights`` takes height fields (.npy, scene units: an sfc-design run's height_field.npy) instead
of the ramp and the dome.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch

from framework.files.mm_outputs import glass_mesh
from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.mesh.path_trace import trace_mesh
from operators.scene import Light, Receiver, Scene, Substrate
from operators.wavefront.renderer import WavefrontRenderer

LIGHT_Z, THICKNESS, HALF = 10.0, 0.1, 1.0  # scene units (25 mm): the paper's light 250 mm above a 2.5 mm substrate


def ramp(m: int) -> np.ndarray:
    """Heights (m, m) rising linearly from 0 at x = -W to 0.2 (5 mm) at x = W."""
    x = np.linspace(-HALF, HALF, m)
    return np.tile(0.1 * (x + HALF), (m, 1))


def dome(m: int) -> np.ndarray:
    """A spherical cap (radius 5) cut by the square: 0.2 at the centre, 0.1 at the edges' midpoints."""
    x = np.linspace(-HALF, HALF, m)
    return np.maximum(np.sqrt(25.0 - x[:, None] ** 2 - x[None, :] ** 2) - 4.8, 0.0)


def scene_for(screen: float, half: float, pixels: int, edge_height: float) -> Scene:
    return Scene(light=Light(position=(0.0, 0.0, LIGHT_Z)),
                 substrate=Substrate(thickness=THICKNESS, half_width=HALF, edge_height=edge_height),
                 receiver=Receiver(z=screen, resolution=pixels, half_width=half))


def compare(heights: np.ndarray, screen: float, half: float, args: argparse.Namespace,
            folder: Path) -> dict[str, float]:
    """The distances (relative L2 over the receiver) of heights (m, m) on the screen at ``screen``
    from their traced mesh."""
    path = folder / "glass.stl"
    glass_mesh(heights, HALF, THICKNESS, 1.0, refine=args.refine).export(path)
    scene = scene_for(screen, half, args.pixels, float(heights.max()))
    halves = [trace_mesh(path, scene.light.position, scene.indices[0], 1.1 * HALF, THICKNESS, screen, half,
                         args.pixels, args.rays // 8, seed=seed, batches=4).image for seed in (0, 1)]
    traced = 0.5 * (halves[0] + halves[1])
    d = torch.from_numpy(heights)

    def distance(image: torch.Tensor) -> float:
        model = image[0].numpy() * scene.receiver.pixel_size ** 2
        return float(np.linalg.norm(model - traced) / np.linalg.norm(traced))

    settings = OperatorSettings(photons=args.photons, dtype="float64")
    dark = dataclasses.replace(scene, substrate=dataclasses.replace(scene.substrate, edge_height=0.0))
    return {"noise": float(np.linalg.norm(halves[0] - halves[1]) / np.linalg.norm(halves[0] + halves[1])),
            "model": distance(CausticOperator(scene, settings).render(d)),
            "exact": distance(WavefrontRenderer(scene, vertices=513).render(d)),
            "dark_rim": distance(CausticOperator(dark, settings).render(d))}


def main(argv: Sequence[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m experiments.benchmarks.bench_raised_edge",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--samples", type=int, default=32, help="height samples per side (default 32)")
    p.add_argument("--refine", type=int, default=8, help="mesh points per height spacing (default 8)")
    p.add_argument("--pixels", type=int, default=32, help="receiver pixels per side (default 32)")
    p.add_argument("--rays", type=int, default=1 << 24, help="traced rays in all (default 16777216)")
    p.add_argument("--photons", type=int, default=1 << 21, help="the model's photons (default 2097152)")
    p.add_argument("--heights", type=Path, nargs="+", help="height fields (.npy, scene units) instead of the ramp "
                                                          "and the dome")
    args = p.parse_args(argv)
    prints: list[tuple[str, Callable[[], np.ndarray]]] = (
        [(str(path), functools.partial(np.load, path)) for path in args.heights] if args.heights
        else [(shape.__name__, functools.partial(shape, args.samples)) for shape in (ramp, dome)])
    print("| print | screen | tracer noise | model | exact renderer | model, rim dark |\n|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        for name, heights in prints:
            for screen, half, label in ((-0.05, 1.05, "1.25 mm"), (-4.0, 2.0, "100 mm")):
                f = compare(heights(), screen, half, args, Path(folder))
                print(f"| {name} | {label} | {f['noise']:.2%} | {f['model']:.2%} | {f['exact']:.2%} | "
                      f"{f['dark_rim']:.2%} |", flush=True)


if __name__ == "__main__":
    main()
