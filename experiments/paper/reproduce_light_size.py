"""The flash's size from two photos: print_lines lit by discs of several diameters, photographed on
two screens, reconstructed with ``calibration.params=[light_size]`` from a wrong start and with the
true size told (docs/method.md, "The extended light").

    python -m experiments.paper.reproduce_light_size scene=gaussian --sizes 20 50 --start 35 --screens 0.05 0.2

The photos are exact caustics (operators/wavefront/extended.py: wavefront renders from points over
the disc with exact pixel coverage, none of the model's photons, footprints or emission points) on
the reconstruction's receiver, with ``--delta`` relative Gaussian noise (seeded).
Each fit is a ``data=stack`` run of two file shots, from ``initial=auto``'s transport start (the
configured height field gives the mask and the volume; it is the truth, so it is not offered as the
design start); every other argument is a Hydra override of conf/reconstruct.yaml. Writes light_size.json and
the runs into --work.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
import torch

from experiments.apps.configs import reconstruct_config
from experiments.apps.input_errors import one_line_input_errors
from framework.reconstruction.reconstruction import run_reconstruction
from framework.scene.scene_config import build_heights, build_scene
from operators.wavefront.extended import ExtendedLightReference

PHOTO_VERTICES = 1025  # wavefront aim points per side of every source point's render


def photo(overrides: list[str], size_mm: float, screen: float, delta: float, seed: int, path: Path,
          vertices: int = PHOTO_VERTICES) -> None:
    """The exact caustic of the configured print under a disc of ``size_mm`` on a screen ``screen``
    below the glass, with noise, saved to ``path`` (.npy, the reconstruction's receiver)."""
    if path.is_file():
        return
    cfg = reconstruct_config([*overrides, "light.shape=disc", f"light.size={size_mm}mm", f"receiver.z={-screen}"])
    clean = ExtendedLightReference(build_scene(cfg), vertices=vertices).render(build_heights(cfg))
    noise = torch.randn(clean.shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    noisy = clean + noise * (delta * float(clean.norm()) / float(noise.norm()))
    np.save(path, noisy.numpy())


def fit(overrides: list[str], photos: list[Path], screens: list[float], size_mm: float, delta: float, volume: float,
        calibrate: bool, run_dir: Path, truth: torch.Tensor, thickness: float) -> dict[str, Any]:
    """A stack reconstruction of ``photos`` with the disc at ``size_mm`` (a start with ``calibrate``);
    its metrics with ``rel_error`` = ||(h + d) - (h + d_true)|| / ||h + d_true|| added."""
    if not (run_dir / "metrics.json").is_file():
        _reconstruct(overrides, photos, screens, size_mm, delta, volume, calibrate, run_dir)
    metrics = json.loads((run_dir / "metrics.json").read_text())
    heights = torch.from_numpy(np.load(run_dir / "height_field.npy"))
    metrics["rel_error"] = float((heights - truth).norm() / (truth + thickness).norm())
    return metrics


def _reconstruct(overrides: list[str], photos: list[Path], screens: list[float], size_mm: float, delta: float,
                 volume: float, calibrate: bool, run_dir: Path) -> None:
    shots = ", ".join(f"{{screen_distance: {s}, image: '{p}'}}" for s, p in zip(screens, photos))
    extra = ["calibration.params=[light_size]"] if calibrate else []
    # The configured height field is the truth: the data must not offer it as the print's design start.
    cfg = reconstruct_config(
        [
            *overrides,
            "~initial.candidates.design",
            "data=stack",
            f"data.shots=[{shots}]",
            "++data.common.source=file",
            f"data.common.delta={delta}",
            "++data.common.mask=design",
            f"++data.common.volume={volume!r}",
            "++data.common.brightness=as_is",
            "light.shape=disc",
            f"light.size={size_mm}mm",
            "tracking.experiment=light_size",
            "defects.enabled=off",
            *extra,
        ]
    )
    run_reconstruction(cfg, run_dir, run_dir.parent)


def study(overrides: list[str], sizes: list[float], start: float, screens: list[float], delta: float,
          work: Path, vertices: int = PHOTO_VERTICES) -> list[dict[str, Any]]:
    """Photos and fits for every disc size; returns one row per size."""
    work.mkdir(parents=True, exist_ok=True)
    cfg = reconstruct_config(overrides)
    heights, scene = build_heights(cfg), build_scene(cfg)
    volume = float(heights.sum()) * (2.0 * scene.substrate.half_width / heights.shape[0]) ** 2
    h = scene.substrate.thickness
    rows = []
    for size in sizes:
        photos = [work / f"disc_{size:g}mm_screen_{s:g}.npy" for s in screens]
        for i, (s, path) in enumerate(zip(screens, photos)):
            photo(overrides, size, s, delta, int(cfg.get("seed", 0)) + 10 * i + int(size), path, vertices)
        told = fit(overrides, photos, screens, size, delta, volume, False, work / f"told_{size:g}mm", heights, h)
        found = fit(overrides, photos, screens, start, delta, volume, True, work / f"calibrated_{size:g}mm", heights, h)
        row = {"size_mm": size, "start_mm": start, "found_mm": found["calibration_light_size_mm"],
               "found_std_mm": found.get("calibration_light_size_std_mm", float("nan")),
               "error_told": told["rel_error"], "error_calibrated": found["rel_error"],
               "iterations_told": told["iterations"], "iterations_calibrated": found["iterations"],
               "discrepancy_over_delta_told": told["rel_discrepancy"] / told["delta"],
               "discrepancy_over_delta_calibrated": found["rel_discrepancy"] / found["delta"],
               "start_told": told["start"], "start_calibrated": found["start"]}
        print(f"disc {size:g} mm: found {row['found_mm']:.2f} mm from {start:g} mm "
              f"({100 * (row['found_mm'] / size - 1):+.1f}%); error {row['error_calibrated']:.4f} against "
              f"{row['error_told']:.4f} told ({100 * (row['error_calibrated'] / row['error_told'] - 1):+.1f}%)",
              flush=True)
        rows.append(row)
    (work / "light_size.json").write_text(json.dumps(rows, indent=2))
    return rows


@one_line_input_errors
def _run(args: argparse.Namespace) -> None:
    study(args.overrides, args.sizes, args.start, args.screens, args.delta, args.work.resolve(), args.vertices)
    print(f"wrote light_size.json to {args.work}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("overrides", nargs="*", help="Hydra overrides of conf/reconstruct.yaml (scene, light height)")
    parser.add_argument("--sizes", nargs="+", type=float, default=[20.0, 50.0], help="the discs' diameters, mm")
    parser.add_argument("--start", type=float, default=35.0, help="the calibrated fit's starting diameter, mm")
    parser.add_argument("--screens", nargs="+", type=float, default=[0.05, 0.2], help="screen distances, scene units")
    parser.add_argument("--delta", type=float, default=0.05, help="relative noise of the photos")
    parser.add_argument("--vertices", type=int, default=PHOTO_VERTICES,
                        help="wavefront aim points per side of every source point's render of the photos")
    parser.add_argument("--work", type=Path, default=Path("outputs/light_size"))
    _run(parser.parse_args(argv))


if __name__ == "__main__":
    main()
