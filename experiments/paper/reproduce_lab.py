"""The lab workflow on synthetic data with a known truth: a photo of the caustic, and a setup
that is not known exactly.

``photo``: the true heights' caustic (screen blur included) is rendered finely, photographed
with a known perspective into a larger 16-bit photo with vignetting, a gamma response, a black
level, noise and a few saturated pixels, with a flat-field photo of the bare substrate beside it;
the photo is imported (data=photo) and reconstructed, and the same reconstruction runs on the
clean render with the same relative noise added (data=file). Reported: the imported image's
error against the render, and both reconstruction errors.

``calibration``: the caustic is rendered with the screen at its true distance and times a camera
gain of 1.7; the reconstruction is told a distance 10% too large and runs once with that setup
fixed (the image scaled to the model's power) and once estimating the distance and the gain with
the heights (calibration.params, the image as it is).

``screen``: the caustic through a Gaussian screen blur of 0.5 and 1.5 receiver pixels, as the
clean render with noise and as the imported photo (both at the photo's noise level); the run told
the blur, the blur found by sfc-calibrate-screen (experiments/apps/calibrate_screen.py) and the run with
the found blur.

    python -m experiments.paper.reproduce_lab                    # all three studies, two scenes each
    python -m experiments.paper.reproduce_lab --study photo --scenes bump
    python -m experiments.paper.reproduce_lab --overrides photons=262144

Writes lab_photo.md / lab_calibration.md / lab_screen.md (and the photo study's figure lab_photo.png) into
--out (default docs/results); every reconstruction is an MLflow run of the experiment ``lab`` in
--store (default mlruns/), its files under --work (default outputs/lab).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from PIL import Image

from experiments.apps.calibrate_screen import calibrate
from experiments.apps.configs import known_print, reconstruct_config
from experiments.paper.mlflow_store import TrackingStore
from framework.core.data import resample_image
from framework.core.truth import height_errors
from framework.lab.calibration import with_setup
from framework.lab.photo_synthesis import synthesize_photo
from framework.reconstruction.parts import Reconstruction
from framework.reconstruction.reconstruction import run_reconstruction
from framework.scene.scene_config import build_heights, build_operator, build_scene, height_grid

SCENES = ("print_lines", "bump")
# The photo: 960 x 720 px, the receiver seen in perspective (about 3.6 photo pixels per receiver
# pixel at n = 128), corners bottom-left, bottom-right, top-right, top-left of the receiver.
PHOTO_SHAPE = (720, 960)
CORNERS = [[230.0, 660.0], [745.0, 640.0], [700.0, 150.0], [265.0, 120.0]]
PHOTO = {"vignetting": 0.3, "gamma": 2.2, "black_level_dn": 512.0, "noise": 0.004, "saturated_pixels": 40}
SCREEN_SIGMA = 0.01  # the screen's blur, scene units (0.25 mm at 25 mm per unit)
TRUE_GAIN, DISTANCE_ERROR = 1.7, 1.10
SCREEN_BLURS_PX = (0.5, 1.5)  # the screen study's Gaussian blurs, receiver pixels


def true_caustic(cfg: dict[str, Any], photons: int, resolution: int, seed: int,
                 setup: dict[str, float] | None = None, heights: torch.Tensor | None = None) -> np.ndarray:
    """The caustic (1, N, N) of the configured (or given) heights by the operator's exact method
    (the height field's wavefront triangles: about ``photons`` vertices, no footprint, no noise;
    ``seed`` for a method that samples) at an N = ``resolution`` receiver, the screen's blur
    included, in the configured setup with ``setup`` (calibration parameter values,
    framework/lab/calibration.py) replaced."""
    scene = build_scene(cfg)
    if setup:
        scene = with_setup(scene, setup)
    operator = build_operator(cfg, scene).exact_variant(photons, seed, resolution)
    d = build_heights(cfg) if heights is None else heights
    return operator.render(d.to(operator.dtype)).double().numpy()


def _save_png16(path: Path, photo: np.ndarray) -> Path:
    Image.fromarray(photo.astype(np.uint16)).save(path)
    return path


def write_photos(cfg: dict[str, Any], work: Path, photons: int, seed: int) -> dict[str, Any]:
    """photo.png and flat.png (16-bit) of the configured heights and of the bare substrate; the
    clean render resampled to the reconstruction's receiver (1, n, n)."""
    fine = 2 * int(cfg["receiver"]["resolution"])
    image = true_caustic(cfg, photons, fine, seed + 1000)
    flat = true_caustic(cfg, photons, fine, seed + 2000, heights=torch.zeros(build_heights(cfg).shape))
    half_width = float(cfg["receiver"]["half_width"])
    # The exposure: the brightest saturated_pixels photo pixels (before vignetting) read two noise
    # sigmas below the import's saturation threshold (0.98 of full scale after the camera's
    # response); those the noise lifts over it saturate.
    brightest = float(image.max())
    linear = synthesize_photo(image / brightest, CORNERS, PHOTO_SHAPE, half_width) / 65535.0
    level = float(np.sort(linear.ravel())[-PHOTO["saturated_pixels"]])
    gain = (0.98 - 2.0 * PHOTO["noise"]) ** PHOTO["gamma"] / (level * brightest)
    common = {"vignetting": PHOTO["vignetting"], "gamma": PHOTO["gamma"],
              "black_level_dn": PHOTO["black_level_dn"], "bit_depth": 16}
    photo = synthesize_photo(image, CORNERS, PHOTO_SHAPE, half_width, gain=gain, noise=PHOTO["noise"], seed=seed,
                             **common)
    flat_photo = synthesize_photo(flat, CORNERS, PHOTO_SHAPE, half_width, gain=0.8 / float(flat.max()),
                                  noise=PHOTO["noise"] / 8, seed=seed + 1, extend_edges=True, **common)
    work.mkdir(parents=True, exist_ok=True)
    clean = resample_image(torch.from_numpy(image), int(cfg["receiver"]["resolution"])).numpy()
    return {"photo": _save_png16(work / "photo.png", photo), "flat": _save_png16(work / "flat.png", flat_photo),
            "clean": clean, "saturated_photo_pixels": int((photo >= 0.98 * 65535).sum())}


def relative_error_after_scale(image: np.ndarray, reference: np.ndarray, weights: np.ndarray) -> float:
    """||w (s image - reference)|| / ||w reference|| with the least-squares scale s."""
    w = weights.astype(np.float64)
    scale = float((w * image * reference).sum() / (w * image * image).sum())
    return float(np.sqrt((w * (scale * image - reference) ** 2).sum() / (w * reference ** 2).sum()))


def _run(overrides: list[str], out: Path, store: TrackingStore, name: str) -> dict[str, Any]:
    cfg = reconstruct_config([*known_print(overrides), "tracking.experiment=lab", *store.overrides()])
    return run_reconstruction(cfg, out / name, out)


def _run_once(overrides: list[str], out: Path, store: TrackingStore, name: str) -> dict[str, Any]:
    """:func:`_run`, or the metrics of its finished run when the study runs again."""
    metrics = out / name / "metrics.json"
    return json.loads(metrics.read_text()) if metrics.is_file() else _run(overrides, out, store, name)


def photo_arguments(files: dict[str, Any], volume: float) -> list[str]:
    """The overrides that import write_photos' photo (data=photo) with the design's mask and volume."""
    return ["data=photo", f"data.photo={files['photo']}", f"data.flat={files['flat']}",
            "data.flat_kind=substrate", "data.response=gamma", f"data.gamma={PHOTO['gamma']}",
            f"data.black_level={PHOTO['black_level_dn']}", "data.mask=design", f"data.volume={volume}",
            f"data.corners={json.dumps(CORNERS, separators=(',', ':'))}"]


def imported_error(base: list[str], photo_args: list[str], files: dict[str, Any], work: Path
                   ) -> tuple[float, np.ndarray]:
    """The imported photo's relative error against the clean render (after the best scale), and the
    import's weights (n, n)."""
    parts = Reconstruction.from_config(reconstruct_config([*base, *photo_args]), work)
    imported = parts.data_source.load(parts.data_request(work, work / "import"))
    weights = imported.weights.numpy()
    return relative_error_after_scale(imported.target.numpy(), files["clean"], weights), weights


def photo_study(scene: str, work: Path, store: TrackingStore, overrides: list[str],
                reference_photons: int = 1 << 22) -> dict[str, Any]:
    """One scene of the photo study: import error and both reconstruction errors; the truth's
    caustic is rendered with ``reference_photons``."""
    base = [f"scene={scene}", "screen.psf=gaussian", f"screen.sigma={SCREEN_SIGMA}", *overrides]
    cfg = reconstruct_config(base)
    files = write_photos(cfg, work / scene, reference_photons, int(cfg["seed"]))
    return photo_against_render(scene, base, cfg, files, photo_arguments, work / scene, store)


def photo_against_render(scene: str, base: list[str], cfg: dict[str, Any], files: dict[str, Any],
                         arguments: Callable[[dict[str, Any], float], list[str]], work: Path,
                         store: TrackingStore) -> dict[str, Any]:
    """The photo's import error, and the reconstructions from the photo (``arguments``' overrides)
    and from the clean render with as much relative noise as the import's error (at least 1%),
    each against the truth."""
    truth, volume = truth_and_volume(cfg)
    photo_args = arguments(files, volume)
    # The imported image's error against the clean render decides the noise level both runs get.
    import_error, weights = imported_error(base, photo_args, files, work)
    delta = max(import_error, 0.01)
    np.save(work / "clean_noisy.npy", with_noise(files["clean"], delta, int(cfg["seed"])))
    from_photo = _run([*base, *photo_args, f"data.delta={delta}"], work, store, "photo")
    from_clean = _run([*base, "data=file", f"data.image={work / 'clean_noisy.npy'}", "data.mask=design",
                       f"data.volume={volume}", f"data.delta={delta}"], work, store, "clean")
    return {"scene": scene, "import_error": import_error, "delta": delta,
            "saturated_photo_pixels": files["saturated_photo_pixels"],
            "weighted_out": int((weights == 0).sum()), "photo_error": error_against(truth, work / "photo", cfg),
            "clean_error": error_against(truth, work / "clean", cfg), "photo_iterations": from_photo["iterations"],
            "clean_iterations": from_clean["iterations"]}


def truth_and_volume(cfg: dict[str, Any]) -> tuple[torch.Tensor, float]:
    """The configured heights (m, m) and their volume (scene units^3), as data=synthetic takes it."""
    truth = build_heights(cfg)
    return truth, float(truth.sum()) * height_grid(cfg, build_scene(cfg)).cell_area


def with_noise(image: np.ndarray, delta: float, seed: int) -> np.ndarray:
    """``image`` plus Gaussian noise of relative norm ``delta`` (seeded)."""
    noise = np.random.default_rng(seed).normal(size=image.shape)
    return image + noise * delta * np.linalg.norm(image) / np.sqrt(image.size)


def error_against(truth: torch.Tensor, run_dir: Path, cfg: dict[str, Any]) -> float:
    """The run's relative error of h + d against h + d_true (framework/core/truth.py, height_errors)."""
    d = torch.from_numpy(np.load(run_dir / "height_field.npy"))
    return height_errors(d, truth, float(cfg["substrate"]["thickness"]))["rel_error"]


def calibration_study(scene: str, work: Path, store: TrackingStore, overrides: list[str],
                      reference_photons: int = 1 << 22) -> dict[str, Any]:
    """One scene of the calibration study: fixed (distance 10% off) against joint calibration; the
    data are the mean of two renders with ``reference_photons`` each."""
    cfg = reconstruct_config([f"scene={scene}", *overrides])
    seed = int(cfg["seed"])
    true_distance = -float(cfg["receiver"]["z"])
    fine = 2 * int(cfg["receiver"]["resolution"])
    renders = [true_caustic(cfg, reference_photons, fine, seed + offset) for offset in (1000, 2000)]
    n = int(cfg["receiver"]["resolution"])
    clean = TRUE_GAIN * resample_image(torch.from_numpy(0.5 * (renders[0] + renders[1])), n).numpy()
    delta = float(cfg["data"]["delta"])
    (work / scene).mkdir(parents=True, exist_ok=True)
    np.save(work / scene / "caustic.npy", with_noise(clean, delta, seed))
    truth, volume = truth_and_volume(cfg)
    data = [f"scene={scene}", "data=file", f"data.image={work / scene / 'caustic.npy'}", "data.mask=design",
            f"data.volume={volume}", f"data.delta={delta}", f"receiver.z={-DISTANCE_ERROR * true_distance}",
            *overrides]
    fixed = _run(data, work / scene, store, "fixed")
    told_truth = _run([*data, f"receiver.z={-true_distance}"], work / scene, store, "fixed_true_distance")
    # The fixed run scales the image to the model's power (brightness: energy), the best it can do
    # without a gain; the joint run takes the values as they are and estimates the gain.
    joint = _run([*data, "data.brightness=as_is", "calibration.params=[gain,screen_distance]"], work / scene, store,
                 "joint")
    return {
        "scene": scene,
        "true_distance": true_distance,
        "start_distance": DISTANCE_ERROR * true_distance,
        "fixed_error": error_against(truth, work / scene / "fixed", cfg),
        "true_distance_error": error_against(truth, work / scene / "fixed_true_distance", cfg),
        "true_distance_discrepancy": told_truth["rel_discrepancy"],
        "distance_at_bound": joint["calibration_screen_distance_at_bound"],
        "joint_error": error_against(truth, work / scene / "joint", cfg),
        "fixed_discrepancy": fixed["rel_discrepancy"],
        "joint_discrepancy": joint["rel_discrepancy"],
        "distance": joint["calibration_screen_distance"],
        "distance_std": joint.get("calibration_screen_distance_std"),
        "gain": joint["calibration_gain"],
        "gain_std": joint["calibration_gain_std"],
        "fixed_iterations": fixed["iterations"],
        "joint_iterations": joint["iterations"],
    }


def screen_study(scene: str, sigma_px: float, source: str, work: Path, store: TrackingStore, overrides: list[str],
                 reference_photons: int = 1 << 22) -> dict[str, Any]:
    """One case of the screen-blur study: ``scene``'s caustic through a Gaussian screen blur of
    ``sigma_px`` receiver pixels, as a photo (``source`` "photo": write_photos' camera, imported) or
    as the clean render with noise of the photo's level ("render"); the run told the blur, the blur
    found by its profile (experiments/apps/calibrate_screen.py) and the run with the found blur."""
    pixel = build_scene(reconstruct_config([f"scene={scene}", *overrides])).receiver.pixel_size
    base = [f"scene={scene}", "screen.psf=gaussian", f"screen.sigma={sigma_px * pixel!r}", *overrides]
    cfg = reconstruct_config(base)
    seed, case = int(cfg["seed"]), work / f"{scene}_{sigma_px:g}px"
    files = write_photos(cfg, case, reference_photons, seed)
    truth, volume = truth_and_volume(cfg)
    photo_args = photo_arguments(files, volume)
    delta = max(imported_error(base, photo_args, files, case)[0], 0.01)
    if source == "photo":
        data = [*photo_args, f"data.delta={delta}"]
    else:
        np.save(case / "render_noisy.npy", with_noise(files["clean"], delta, seed))
        data = ["data=file", f"data.image={case / 'render_noisy.npy'}", "data.mask=design", f"data.volume={volume}",
                f"data.delta={delta}"]
    out = case / source
    told = _run_once([*base, *data], out, store, "told")
    found = calibrate([f"scene={scene}", *overrides, *data, *store.overrides()], out / "profile")
    row = {"scene": scene, "source": source, "true_px": sigma_px, "delta": delta, "found_px": found["sigma_px"],
           "identified": found["identified"], "rise": found["rise_at_factor_2"],
           "profile_runs": len(found["profile"]), "told_error": error_against(truth, out / "told", cfg),
           "told_iterations": told["iterations"], "told_over_delta": told["discrepancy_over_delta"],
           "found_error": None, "found_iterations": None, "found_over_delta": None}
    if found["identified"]:
        name = f"found_{found['sigma_px']:.4f}px"
        run = _run_once([f"scene={scene}", "screen.psf=gaussian", f"screen.sigma={found['sigma']!r}", *overrides,
                         *data], out, store, name)
        row.update(found_error=error_against(truth, out / name, cfg), found_iterations=run["iterations"],
                   found_over_delta=run["discrepancy_over_delta"])
    return row


def photo_table(rows: list[dict[str, Any]]) -> str:
    lines = ["| scene | imported vs render (rel.) | saturated photo px | receiver px weighted 0 | delta | "
             "rel. err. from the photo | rel. err. from the render | ratio |", "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['scene']} | {r['import_error']:.4f} | {r['saturated_photo_pixels']} | {r['weighted_out']} | "
              f"{r['delta']:.4f} | {r['photo_error']:.4f} | {r['clean_error']:.4f} | "
              f"{r['photo_error'] / r['clean_error']:.3f} |" for r in rows]
    return "\n".join(lines) + "\n"


def _distance(row: dict[str, Any]) -> str:
    """The recovered distance with its standard error, or why there is none."""
    if row["distance_std"] is None:
        return f"{row['distance']:.5f}, not calibrated (noise level met at iteration {row['joint_iterations']})"
    return f"{row['distance']:.5f} ± {row['distance_std']:.5f}{' (at its bound)' if row['distance_at_bound'] else ''}"


def calibration_table(rows: list[dict[str, Any]]) -> str:
    lines = ["| scene | true distance | told | rel. err. told / true distance | rel. dis. told / true distance | "
             "rel. err. joint | rel. dis. joint | recovered distance (std at fixed heights) | "
             f"recovered gain (true {TRUE_GAIN}) |", "|---|---|---|---|---|---|---|---|---|"]
    lines += [
        f"| {r['scene']} | {r['true_distance']:.4f} | {r['start_distance']:.4f} | {r['fixed_error']:.4f} / "
        f"{r['true_distance_error']:.4f} | {r['fixed_discrepancy']:.4f} / {r['true_distance_discrepancy']:.4f} | "
        f"{r['joint_error']:.4f} | {r['joint_discrepancy']:.4f} | {_distance(r)} "
        f"| {r['gain']:.4f} ± {r['gain_std']:.4f} |"
        for r in rows
    ]
    return "\n".join(lines) + "\n"


def screen_table(rows: list[dict[str, Any]]) -> str:
    lines = ["| scene | data | true blur (px) | delta | found blur (px) | found / true | misfit rise at x2 | fits | "
             "told: rel. err. (it., dis./delta) | found: rel. err. (it., dis./delta) | ratio |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        found = (f"{r['found_error']:.4f} ({r['found_iterations']}, {r['found_over_delta']:.2f}) | "
                 f"{r['found_error'] / r['told_error']:.3f}" if r["found_error"] is not None else "not told | -")
        lines.append(f"| {r['scene']} | {r['source']} | {r['true_px']:g} | {r['delta']:.4f} | {r['found_px']:.3f} | "
                     f"{r['found_px'] / r['true_px']:.3f} | {100 * r['rise']:.0f}% | {r['profile_runs']} | "
                     f"{r['told_error']:.4f} ({r['told_iterations']}, {r['told_over_delta']:.2f}) | {found} |")
    return "\n".join(lines) + "\n"


def study_parser(description: str, work: str) -> argparse.ArgumentParser:
    """The options of a lab study: --scenes, --store, --tracking-uri, --work (default ``work``),
    --out, --reference-photons, --overrides."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--scenes", nargs="+", default=list(SCENES))
    parser.add_argument("--store", type=Path, default=Path("mlruns"), help="MLflow store directory")
    parser.add_argument("--tracking-uri", default=None, help="a shared MLflow tracking server instead of --store")
    parser.add_argument("--work", type=Path, default=Path(work))
    parser.add_argument("--out", type=Path, default=Path("docs/results"))
    parser.add_argument("--reference-photons", type=int, default=1 << 22, help="photons of the truth's renders")
    parser.add_argument("--overrides", nargs="*", default=[], help="extra Hydra overrides for every run")
    return parser


def main(argv: list[str] | None = None) -> None:
    parser = study_parser(__doc__.splitlines()[0], "outputs/lab")
    parser.add_argument("--study", choices=("photo", "calibration", "screen", "all"), default="all")
    parser.add_argument("--blurs", nargs="+", type=float, default=list(SCREEN_BLURS_PX),
                        help="the screen study's blurs, receiver pixels")
    parser.add_argument("--sources", nargs="+", choices=("render", "photo"), default=["render", "photo"],
                        help="the screen study's data: the render with noise, the imported photo")
    args = parser.parse_args(argv)
    store, work = TrackingStore(args.store.resolve(), args.tracking_uri), args.work.resolve()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.study in ("photo", "all"):
        rows = [photo_study(s, work / "photo", store, args.overrides, args.reference_photons) for s in args.scenes]
        (args.out / "lab_photo.md").write_text(photo_table(rows))
        print(photo_table(rows))
    if args.study in ("calibration", "all"):
        rows = [calibration_study(s, work / "calibration", store, args.overrides, args.reference_photons)
                for s in args.scenes]
        (args.out / "lab_calibration.md").write_text(calibration_table(rows))
        print(calibration_table(rows))
    if args.study in ("screen", "all"):
        rows = [screen_study(s, b, source, work / "screen", store, args.overrides, args.reference_photons)
                for source in args.sources for s in args.scenes for b in args.blurs]
        (args.out / "lab_screen.md").write_text(screen_table(rows))
        print(screen_table(rows))


if __name__ == "__main__":
    main()
