"""The lab's bench as a camera sees it, on synthetic data with a known truth
(framework/lab/synthetic_bench.py): the true heights' exact caustic on a screen framed by the
marker sheet, photographed obliquely at 3000 x 2250 px (the receiver about 1400 px wide, 11 photo
pixels a receiver pixel at 128) through a lens with 0.9% barrel distortion,
with vignetting and 0.5% noise, written as camera RAW (DNG), with a flat field of the evenly lit
screen; the lens calibrated from six photos of a ChArUco board. The photo is imported with no
corners typed (data.markers, data.lens) and reconstructed, and the same reconstruction runs on the
clean render with the same relative noise added (data=file), as the photo study of
experiments/paper/reproduce_lab.py does with typed corners.

    python -m experiments.paper.reproduce_bench                   # print_lines and the bump
    python -m experiments.paper.reproduce_bench --scenes bump

Writes lab_bench.md into --out (default docs/results); every reconstruction is an MLflow run of the
experiment ``lab`` in --store (default mlruns/), its files under --work (default outputs/bench).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from experiments.apps.configs import reconstruct_config
from experiments.paper.mlflow_store import TrackingStore
from experiments.paper.reproduce_lab import (SCREEN_SIGMA, photo_against_render, photo_table, study_parser,
                                             true_caustic)
from framework.core.data import resample_image
from framework.lab.lens import CharucoBoard, calibrate_lens
from framework.lab.photo_synthesis import write_dng
from framework.lab.synthetic_bench import SyntheticBench

BENCH = SyntheticBench(size=(3000, 2250), camera_matrix=((4200.0, 0.0, 1500.0), (0.0, 4200.0, 1125.0),
                                                          (0.0, 0.0, 1.0)))
BRIGHTEST = 0.85  # the caustic's brightest page value (fraction of full scale before vignetting)
NOISE, FLAT_NOISE = 0.005, 0.0025  # fractions of full scale: a RAW at base ISO; the flat, four exposures averaged


def write_bench(cfg: dict[str, Any], work: Path, photons: int, seed: int) -> dict[str, Any]:
    """print.dng, flat.dng, sheet.json and lens.json of the configured heights on the bench, and the
    clean render on the reconstruction's receiver (1, n, n)."""
    image = true_caustic(cfg, photons, BENCH.receiver_pixels(), seed + 1000)[0]
    irradiance = np.flipud(image) * (BRIGHTEST / float(image.max()))  # row 0 = the receiver's top
    photo = BENCH.photograph(BENCH.page(irradiance), NOISE, seed)
    flat = BENCH.photograph(BENCH.page(None), FLAT_NOISE, seed + 1)
    work.mkdir(parents=True, exist_ok=True)
    board = CharucoBoard()
    lens = calibrate_lens(BENCH.board_photos(board), board).save(work / "lens.json")
    _, sheet = BENCH.sheet.save(work / "sheet", dpi=BENCH.per_mm * 25.4)
    n = int(cfg["receiver"]["resolution"])
    fine = true_caustic(cfg, photons, 2 * n, seed + 1000)
    return {"photo": write_dng(work / "print.dng", np.repeat(photo[..., None], 3, axis=2)),
            "flat": write_dng(work / "flat.dng", np.repeat(flat[..., None], 3, axis=2)), "lens": lens,
            "sheet": sheet, "clean": resample_image(torch.from_numpy(fine), n).numpy(),
            "saturated_photo_pixels": int((photo >= 0.98).sum())}


def bench_arguments(files: dict[str, Any], volume: float) -> list[str]:
    """The overrides that import the bench's photo (data=photo) with the design's mask and volume."""
    return ["data=photo", f"data.photo={files['photo']}", f"data.markers={files['sheet']}",
            f"data.lens={files['lens']}", f"data.flat={files['flat']}", "data.flat_kind=uniform",
            "data.channel=green", "data.mask=design", f"data.volume={volume}"]


def bench_study(scene: str, work: Path, store: TrackingStore, overrides: list[str],
                reference_photons: int = 1 << 22) -> dict[str, Any]:
    """One scene: the imported image's error and both reconstruction errors."""
    base = [f"scene={scene}", "screen.psf=gaussian", f"screen.sigma={SCREEN_SIGMA}", *overrides]
    cfg = reconstruct_config(base)
    files = write_bench(cfg, work / scene, reference_photons, int(cfg["seed"]))
    return photo_against_render(scene, base, cfg, files, bench_arguments, work / scene, store)


def main(argv: list[str] | None = None) -> None:
    args = study_parser(__doc__.splitlines()[0], "outputs/bench").parse_args(argv)
    store, work = TrackingStore(args.store.resolve(), args.tracking_uri), args.work.resolve()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = [bench_study(s, work, store, args.overrides, args.reference_photons) for s in args.scenes]
    (args.out / "lab_bench.md").write_text(photo_table(rows))
    print(photo_table(rows))


if __name__ == "__main__":
    main()
