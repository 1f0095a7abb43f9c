"""Several photos of one print (data=stack, docs/method.md "Several photos"): how a second and a
third screen distance change the reconstruction, and the lab study with two photos.

- ``screens``: print_lines and letter_a from 1, 2 and 3 screens (0.05, 0.2, 1.0 below the
  substrate), the same total photons (``photons`` split over the shots) and the same noise
  level per image, and the Fig. 7 distance (1.0) with a near screen (0.05); several screens
  with the weightings of the shots' misfits (data.weighting: equal, distance, noise).
- ``lab``: the caustics at the true screen distance 0.05 and 0.15 farther (a translation stage),
  times camera gains of 1.7 and 1.3, with 5% noise; the reconstruction is told a distance 10% too
  large and estimates it with both gains (calibration.params=[gain, screen_distance]), beside the
  run told the true distance.

    python -m experiments.paper.reproduce_stack                  # both parts, then the tables
    python -m experiments.paper.reproduce_stack --part screens --scenes print_lines --weightings equal distance

Writes stack_screens.md/.csv and stack_lab.md into --out (default docs/results); every
reconstruction is an MLflow run of the experiment ``stack`` in --store (default mlruns/), its
files under --work (default outputs/stack).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
import torch

from experiments.apps.configs import known_print, reconstruct_config
from experiments.paper.mlflow_store import TrackingStore
from experiments.paper.reproduce_lab import error_against, true_caustic, truth_and_volume, with_noise
from experiments.paper.tables import write_csv
from framework.core.data import resample_image
from framework.reconstruction.reconstruction import run_reconstruction
from framework.stack.stack_data import StackData

SCREEN_SETS = ((0.05,), (0.05, 0.2), (0.05, 0.2, 1.0), (1.0, 0.05))
WEIGHTINGS = StackData.WEIGHTINGS  # data.weighting
TOTAL_PHOTONS = 1 << 20  # split over the shots: each traces TOTAL_PHOTONS / N per evaluation
LAB_DISTANCES, LAB_GAINS, DISTANCE_ERROR = (0.05, 0.2), (1.7, 1.3), 1.10


def shots_override(distances: tuple[float, ...], extra: list[dict[str, Any]] | None = None) -> str:
    """``data.shots=[...]`` for screens at ``distances`` (with per-shot ``extra`` keys)."""
    shots = [{"screen_distance": z, **((extra or [{}] * len(distances))[i])} for i, z in enumerate(distances)]
    return "data.shots=" + json.dumps(shots, separators=(",", ":")).replace('"', "")


def _run(overrides: list[str], out: Path, store: TrackingStore, name: str) -> dict[str, Any]:
    cfg = reconstruct_config([*known_print(overrides), "tracking.experiment=stack", *store.overrides()])
    return run_reconstruction(cfg, out / name, out)


def screens_study(scene: str, distances: tuple[float, ...], weighting: str, work: Path, store: TrackingStore,
                  overrides: list[str], total_photons: int = TOTAL_PHOTONS) -> dict[str, Any]:
    """One reconstruction of ``scene`` from synthetic caustics at ``distances`` (data.weighting),
    ``total_photons`` per evaluation split over the shots."""
    photons = total_photons // len(distances)
    name = "_".join(f"{z:g}" for z in distances) + f"_{weighting}"
    metrics = _run([f"scene={scene}", "data=stack", shots_override(distances), f"photons={photons}",
                    f"data.weighting={weighting}", *overrides], work / scene, store, name)
    first = {k[len("start_"):]: v for k, v in metrics.items() if k.startswith("start_") and "_first_fit_" in k}
    first_iterations = int(first.get(f"{metrics['start']}_first_fit_iterations", 0))  # of the run returned
    return {"scene": scene, "screens": " + ".join(f"{z:g}" for z in distances), "weighting": weighting,
            "photons_per_shot": photons, "first_fit_iterations": first_iterations,
            **{k: metrics[k] for k in ("iterations", "stop_reason", "rel_discrepancy", "rel_error",
                                        "start")},
            "photon_traces": metrics["photon_traces"] + sum(v for k, v in first.items()
                                                            if k.endswith("first_fit_photon_traces")),
            "shot_discrepancies": " / ".join(f"{metrics[f'shot{i}_rel_discrepancy']:.4f}"
                                             for i in range(len(distances)))}


def lab_study(scene: str, work: Path, store: TrackingStore, overrides: list[str],
              reference_photons: int = 1 << 22) -> dict[str, Any]:
    """Two photos 0.15 apart, the distance told 10% too large: fixed true geometry against joint
    calibration of the distance and both gains."""
    cfg = reconstruct_config([f"scene={scene}", *overrides])
    seed, n = int(cfg["seed"]), int(cfg["receiver"]["resolution"])
    delta = float(cfg["data"]["delta"])
    (work / scene).mkdir(parents=True, exist_ok=True)
    files = []
    for i, (z, gain) in enumerate(zip(LAB_DISTANCES, LAB_GAINS)):
        renders = [true_caustic(cfg, reference_photons, 2 * n, seed + 10 * i + k, {"screen_distance": z})
                   for k in (1000, 2000)]
        clean = gain * resample_image(torch.from_numpy(0.5 * (renders[0] + renders[1])), n).numpy()
        files.append(work / scene / f"caustic_{z:g}.npy")
        np.save(files[-1], with_noise(clean, delta, seed + i))
    truth, volume = truth_and_volume(cfg)
    told = DISTANCE_ERROR * LAB_DISTANCES[0]
    offsets = [z - LAB_DISTANCES[0] for z in LAB_DISTANCES]
    shots = "data.shots=" + json.dumps([{"image": str(f), "offset": o} for f, o in zip(files, offsets)],
                                       separators=(",", ":")).replace('"', "")
    data = [f"scene={scene}", "data=stack", shots, "data.common.source=file", "+data.common.mask=design",
            f"+data.common.volume={volume}", f"data.common.delta={delta}", *overrides]
    true = _run([*data, f"receiver.z={-LAB_DISTANCES[0]}", "+data.common.brightness=energy"], work / scene, store,
                "true_geometry")
    joint = _run([*data, f"receiver.z={-told}", "+data.common.brightness=as_is",
                  "calibration.params=[gain,screen_distance]"], work / scene, store, "joint")
    return {"scene": scene, "true_distance": LAB_DISTANCES[0], "told": told,
            "distance": joint["calibration_screen_distance"], "distance_std": joint["calibration_screen_distance_std"],
            "gains": [joint[f"calibration_gain_{i}"] for i in range(2)],
            "gain_stds": [joint[f"calibration_gain_{i}_std"] for i in range(2)],
            "true_error": error_against(truth, work / scene / "true_geometry", cfg),
            "joint_error": error_against(truth, work / scene / "joint", cfg),
            "true_discrepancy": true["rel_discrepancy"], "joint_discrepancy": joint["rel_discrepancy"],
            "true_iterations": true["iterations"], "joint_iterations": joint["iterations"]}


def screens_table(rows: list[dict[str, Any]]) -> str:
    lines = ["| scene | screens | weighting | photons per shot | start | it. (nearest first + stack) | "
             "rel. dis. (per shot) | rel. err. | G photon-traces (all starts) | stop |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['scene']} | {r['screens']} | {r['weighting']} | {r['photons_per_shot']} | {r['start']} | "
              f"{r['first_fit_iterations']} + {r['iterations']} | "
              f"{r['rel_discrepancy']:.4f} ({r['shot_discrepancies']}) | {r['rel_error']:.4f} | "
              f"{r['photon_traces'] / 1e9:.3f} | {r['stop_reason'].split(':')[0]} |" for r in rows]
    return "\n".join(lines) + "\n"


def lab_table(rows: list[dict[str, Any]]) -> str:
    lines = ["| scene | true distance | told | recovered distance (std) | distance error | recovered gains "
             f"(true {LAB_GAINS[0]}, {LAB_GAINS[1]}) | rel. err. joint / true geometry | rel. dis. joint / true "
             "geometry |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        gains = ", ".join(f"{g:.4f} ± {s:.4f}" for g, s in zip(r["gains"], r["gain_stds"]))
        lines.append(f"| {r['scene']} | {r['true_distance']:.4f} | {r['told']:.4f} | {r['distance']:.5f} ± "
                     f"{r['distance_std']:.5f} | {abs(r['distance'] / r['true_distance'] - 1):.2%} | {gains} | "
                     f"{r['joint_error']:.4f} / {r['true_error']:.4f} | {r['joint_discrepancy']:.4f} / "
                     f"{r['true_discrepancy']:.4f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=("screens", "lab", "all"), default="all")
    parser.add_argument("--scenes", nargs="+", default=["print_lines", "letter_a"])
    parser.add_argument("--screen-sets", nargs="+", default=[",".join(f"{z:g}" for z in s) for s in SCREEN_SETS],
                        help="comma-separated screen distances per case, e.g. 0.05,0.2")
    parser.add_argument("--weightings", nargs="+", default=["equal"], choices=WEIGHTINGS,
                        help="data.weighting of the runs with several screens")
    parser.add_argument("--lab-scenes", nargs="+", default=["print_lines", "bump"])
    parser.add_argument("--total-photons", type=int, default=TOTAL_PHOTONS,
                        help="photons per evaluation of the screens study, split over the shots")
    parser.add_argument("--reference-photons", type=int, default=1 << 22,
                        help="photons of each of the lab study's two renders of the truth per screen")
    parser.add_argument("--store", type=Path, default=Path("mlruns"), help="MLflow store directory")
    parser.add_argument("--tracking-uri", default=None, help="a shared MLflow tracking server instead of --store")
    parser.add_argument("--work", type=Path, default=Path("outputs/stack"))
    parser.add_argument("--out", type=Path, default=Path("docs/results"))
    parser.add_argument("--overrides", nargs="*", default=[], help="extra Hydra overrides for every run")
    args = parser.parse_args(argv)
    store, work = TrackingStore(args.store.resolve(), args.tracking_uri), args.work.resolve()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.part in ("screens", "all"):
        sets = [tuple(float(z) for z in s.split(",")) for s in args.screen_sets]
        rows = [screens_study(scene, s, weighting, work / "screens", store, args.overrides, args.total_photons)
                for scene in args.scenes
                for s in sets for weighting in (args.weightings if len(s) > 1 else ["equal"])]
        (args.out / "stack_screens.md").write_text(screens_table(rows))
        write_csv(args.out / "stack_screens.csv", rows)
        print(screens_table(rows))
    if args.part in ("lab", "all"):
        rows = [lab_study(scene, work / "lab", store, args.overrides, args.reference_photons)
                for scene in args.lab_scenes]
        (args.out / "stack_lab.md").write_text(lab_table(rows))
        print(lab_table(rows))


if __name__ == "__main__":
    main()
