"""One reconstruction, end to end: data -> operator -> solver -> outputs, tracked in MLflow.

Used by ``sfc-reconstruct`` (experiments/reconstruct.py); kept here so that the app stays thin
and tests can run a reconstruction without Hydra's command line.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from framework.callbacks import (Checkpointer, GroundTruthError, MetricsHistory, MorozovStopping, ProgressBar,
                                 StagnationStopping)
from framework.checkpoint import resume as resume_solver
from framework.data import ReconstructionData, measured_data, synthetic_data
from framework.height_field_io import load_height_field
from framework.image_io import load_caustic_image, load_mask
from framework.objective import DataFidelity
from framework.report_figures import save_reconstruction_figures
from framework.scene_config import build_heights, build_operator, build_scene, to_plain
from framework.solver_config import solver_recipe
from framework.solvers import IterationRecord
from framework.tracking import MlflowTracker
from operators.caustic_operator import CausticOperator
from operators.precompile import BackgroundCompile
from operators.scene import Scene
from regularizers import RegularizerContext, mask_from_height_field

CHECKPOINT = "checkpoint.pt"


def height_pixel_area(scene: Scene, resolution: int) -> float:
    """Area a of one height sample (scene units^2): samples are spaced 2 W / (m - 1)."""
    return (2.0 * scene.substrate.half_width / (resolution - 1)) ** 2


def _reference_operator(cfg: Mapping[str, Any], scene: Scene, seed: int) -> CausticOperator:
    """Operator that renders synthetic references: more photons, own receiver size, own seed."""
    data = cfg["data"]
    resolution = int(data["reference_resolution"])
    receiver = dataclasses.replace(scene.receiver, resolution=resolution)
    # Footprints are given in receiver pixels: scale them so the reference blurs like the model.
    zoom = resolution / scene.receiver.resolution
    settings = dict(cfg["operator"])
    for key in ("footprint_px", "min_footprint_px", "max_pixel_radius"):
        if key in settings:
            settings[key] = float(settings[key]) * zoom
    ref_cfg = {**cfg, "photons": int(data["reference_photons"]), "seed": seed, "operator": settings}
    return build_operator(ref_cfg, dataclasses.replace(scene, receiver=receiver))


def build_data(cfg: Mapping[str, Any], scene: Scene, operator: CausticOperator, base_dir: Path) -> ReconstructionData:
    """Synthetic data from the configured height field, or measured data from files (``data.kind``)."""
    data = cfg["data"]
    kind = data["kind"]
    m = int(cfg["height_field"]["resolution"])
    if kind == "synthetic":
        truth = build_heights(cfg, base_dir=base_dir)
        seed = int(cfg["seed"])
        first = _reference_operator(cfg, scene, seed + 1000)
        second = _reference_operator(cfg, scene, seed + 2000)
        return synthetic_data(truth.to(operator.dtype), first.render, second.render, scene.receiver.resolution,
                              float(data["delta"]), seed, height_pixel_area(scene, m),
                              float(data["mask_threshold"]), float(data["mask_dilation"]))
    if kind == "file":
        if not data.get("image"):
            raise ValueError("data.kind=file needs data.image=<caustic .npy/.png/.tif>")
        image = load_caustic_image(_resolve(data["image"], base_dir))
        if image.shape[0] != scene.channels:
            raise ValueError(f"data.image has {image.shape[0]} channel(s) but the scene has {scene.channels} "
                             "wavelength(s); set wavelengths=[...] to match")
        mask_spec = data.get("mask")
        if mask_spec in (None, "none"):
            mask = torch.ones(m, m, dtype=torch.bool)
        elif mask_spec == "design":
            mask = mask_from_height_field(build_heights(cfg, base_dir=base_dir), float(data["mask_threshold"]),
                                          float(data["mask_dilation"]))
        else:
            mask = load_mask(_resolve(mask_spec, base_dir), m)
        flat_total = None
        if data.get("brightness", "energy") == "energy":
            flat_total = float(operator.render(torch.zeros(m, m, dtype=operator.dtype)).sum())
        volume = data.get("volume")
        return measured_data(image, scene.receiver.resolution, float(data["delta"]), mask,
                             None if volume is None else float(volume), flat_total)
    raise ValueError(f"unknown data.kind {kind!r}; use synthetic or file")


def _resolve(path: str, base_dir: Path) -> Path:
    p = Path(path).expanduser()
    return p if p.is_absolute() else base_dir / p


def initial_heights(cfg: Mapping[str, Any], m: int, dtype: torch.dtype, base_dir: Path) -> torch.Tensor:
    """The iteration's start d0 (m, m), scene units, from ``initial``: ``zero`` (flat glass, the
    paper), ``design`` (the configured height field, with ``data=file`` the print's design) or
    the path of a .npy/.png height field (resampled to m), each times ``initial_scale``."""
    spec = cfg.get("initial", "zero")
    scale = cfg.get("initial_scale", 1.0)
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0.0 <= scale < float("inf"):
        raise ValueError(f"initial_scale={scale!r} must be a finite number >= 0, e.g. 0.5")
    if spec in (None, "zero"):
        return torch.zeros(m, m, dtype=dtype)
    if spec == "design":
        d = build_heights(cfg, base_dir=base_dir) * float(scale)
    else:
        d = torch.from_numpy(load_height_field(_resolve(str(spec), base_dir), resolution=m, scale=float(scale)))
    if tuple(d.shape) != (m, m):
        raise ValueError(f"initial={spec!r} gives heights of shape {tuple(d.shape)}, the reconstruction has "
                         f"({m}, {m}); set height_field.resolution to match")
    return d.to(dtype)


def volume_band(solver: Any) -> tuple[float, float] | None:
    """The band [q1, q2] of the height sum that the solver's volume regulariser (V1 or V2)
    enforces, or None when it has none."""
    for part in [*getattr(solver, "regularizers", []), *getattr(solver, "post_steps", [])]:
        band = getattr(part, "band", None)
        if band is not None:
            return band
    return None


def stage_changes(history: Sequence[IterationRecord]) -> list[int]:
    """Iterations after which the preconditioner moved to its next length, whether the stagnation
    rule or a failed line search asked for it (from the records' ``preconditioner_length``)."""
    lengths = [(r.iteration, r.extras.get("preconditioner_length")) for r in history]
    return [i for (i, a), (_, b) in zip(lengths, lengths[1:]) if a is not None and b is not None and a != b]


def run_reconstruction(cfg: Mapping[str, Any], output_dir: Path, base_dir: Path,
                       sweep_id: str | None = None) -> dict[str, Any]:
    """Reconstruct the configured scene into ``output_dir``; returns the metrics written to metrics.json."""
    output_dir.mkdir(parents=True, exist_ok=True)
    on_cpu = not str(cfg.get("operator", {}).get("device", "cpu")).startswith("cuda")
    with BackgroundCompile(enabled=bool(cfg.get("compile_in_background", True)) and on_cpu) as compiling:
        return _reconstruct(cfg, output_dir, base_dir, sweep_id, compiling)


def _reconstruct(cfg: Mapping[str, Any], output_dir: Path, base_dir: Path, sweep_id: str | None,
                 compiling: BackgroundCompile) -> dict[str, Any]:
    # Everything built from config alone comes first, so that a bad value fails before the data's renders.
    scene = build_scene(cfg)
    operator = build_operator(cfg, scene)
    m = int(cfg["height_field"]["resolution"])
    d0 = initial_heights(cfg, m, operator.dtype, base_dir)
    recipe = solver_recipe(cfg["solver"], cfg.get("regularizers"), cfg.get("post_steps"), cfg.get("wavelet"), (m, m))
    patience = cfg["solver"].get("patience")
    stagnation = StagnationStopping(patience) if patience is not None else None
    tracking = cfg["tracking"]
    tags = {"method": cfg.get("method", "custom"), "scene": cfg["height_field"].get("shape", "file"),
            "data": cfg["data"]["kind"]}
    with MlflowTracker(experiment=tracking["experiment"], run_name=cfg.get("method"),
                       store_dir=_resolve(tracking["store_dir"], base_dir), tracking_uri=tracking.get("uri"),
                       params=to_plain(cfg), tags=tags, sweep_id=sweep_id) as tracker:
        start = time.perf_counter()
        data = build_data(cfg, scene, operator, base_dir)
        data_seconds = time.perf_counter() - start
        cell_area = height_pixel_area(scene, m)
        context = RegularizerContext(mask=data.mask, volume=data.volume, pixel_area=cell_area)
        fidelity = DataFidelity(operator, data.target.to(operator.dtype), cell_area=cell_area)
        solver = recipe.build(fidelity, d0, context)
        history = MetricsHistory()
        callbacks = [history, MorozovStopping(data.delta, float(cfg["solver"]["tau_dis"]), volume_band(solver)),
                     ProgressBar(desc=str(cfg.get("method", "reconstruct"))),
                     Checkpointer(output_dir / CHECKPOINT, every=int(cfg["checkpoint_every"])),
                     tracker.metrics_callback()]
        if stagnation is not None:
            callbacks.append(stagnation)
        truth_error = None
        if data.ground_truth is not None:
            truth_error = GroundTruthError(data.ground_truth.to(operator.dtype), scene.substrate.thickness)
            callbacks.append(truth_error)
        max_iter = int(cfg["solver"]["max_iter"])
        if compiling.running:
            print("waiting for the gradient kernel to compile (first run after an install; cached afterwards)",
                  flush=True)
        compiling.wait()
        solve_start = time.perf_counter()
        if cfg.get("resume"):
            result = resume_solver(solver, _resolve(str(cfg["resume"]), base_dir), max_iter, callbacks)
        else:
            result = solver.run(max_iter, callbacks)
        solve_seconds = time.perf_counter() - solve_start
        d = result.d.detach()
        returned_iteration = result.iterations
        if result.stopped_by != "MorozovStopping" and stagnation is not None and stagnation.best_d is not None:
            # No admissible iterate: return the one with the lowest discrepancy seen.
            d, returned_iteration = stagnation.best_d, stagnation.best_iteration
        prediction = operator.render(d)
        residual = float(torch.linalg.vector_norm((prediction - data.target.to(prediction)).double()))
        metrics: dict[str, Any] = {
            "method": cfg.get("method", "custom"), "iterations": result.iterations,
            "returned_iteration": returned_iteration,
            "refined_at": stage_changes(result.history),
            "stop_reason": result.stop_reason, "stopped_by": result.stopped_by,
            "run_time_s": solve_seconds, "data_time_s": data_seconds,
            "rel_discrepancy": residual / float(torch.linalg.vector_norm(data.target.double())),
            "delta": data.delta, "intrinsic_noise": data.intrinsic_noise,
            "photons_per_iteration": operator.photons, **(truth_error.errors(d) if truth_error else {})}
        np.save(output_dir / "height_field.npy", d.cpu().numpy().astype(np.float64))
        (output_dir / "metrics.json").write_text(json.dumps(metrics, indent=2))
        save_reconstruction_figures(output_dir, d, data, prediction, history.columns(), scene)
        tracker.log_metrics({k: v for k, v in metrics.items() if isinstance(v, (int, float)) and v is not None
                             and not isinstance(v, bool)})
        tracker.log_artifacts(output_dir)
    return metrics
