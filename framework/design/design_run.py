"""One caustic design, end to end (docs/design.md): target and limits checked -> the method's start
-> its solver within the time budget -> the nearest printable design -> its caustic rendered
independently at the design distance and the preview distances -> files, verdict, MLflow.

Used by ``sfc-design`` (experiments/apps/design.py). The methods (config group ``design_method``): ``sfc``
(the transport design, then L-BFGS on the differentiable operator), ``schwartzburg`` (the
transport design alone) and ``adam`` (Adam from flat glass, the Mitsuba 3 tutorial's method).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from framework.core.contracts.run_log import RunLog
from framework.core.callbacks import Checkpointer, MetricsHistory, ProgressBar
from framework.core.checkpoint import restore
from framework.core.contracts.start import StartRequest
from framework.core.data import ReconstructionData
from framework.core.image_metrics import relative_l2, ssim
from framework.core.plugin_config import build_plugin, plugin_class, split_name
from framework.core.problem import Problem
from framework.core.progress import phase
from framework.core.solver_loop import Callback
from framework.design.print_constraints import DesignProblem
from framework.design.design_report import save_design_figure, save_previews
from framework.design.design_screen import has_elements
from framework.design.design_setup import DesignSetup, prepare_design
from framework.files.mm_outputs import export_outputs
from operators.mesh.elements import PrintReachesElement
from operators.wavefront.renderer import WavefrontRenderer, wavefront_vertices

__all__ = ["DesignResult", "design_verdict", "run_design", "wall_light"]

CHECKPOINT = "checkpoint.pt"
THROUGH_OPTICS_REACH = 0.999  # through optical elements the transport may send light anywhere on the screen
START_SHARE = 0.5  # the transport start's Newton stops after this share of the time budget
WALL_LIGHT_NOTED = 1e-3  # the verdict names the side walls' light above this share of the caustic


@dataclass
class DesignResult:
    """The end of a design: the printable heights (m, m), scene units, and the run's figures."""

    heights: np.ndarray
    metrics: dict[str, float]
    verdict: list[str]


class TimeBudget(Callback):
    """Stops the run when the method (its start included) has used ``seconds``; the design then is
    the last iterate (a design has no noise level to stop at)."""

    stop_accepts_iterate = True

    def __init__(self, seconds: float, spent_before: float) -> None:
        self.seconds, self.spent_before = seconds, spent_before

    def on_start(self, solver) -> None:  # noqa: D102  (a step that can stop early ends with the budget)
        solver.deadline = time.perf_counter() + self.seconds - self.spent_before - solver.state.elapsed_s

    def on_iteration(self, solver, record) -> bool:  # noqa: D102
        if self.spent_before + record.elapsed_s >= self.seconds:
            self.stop_reason = f"the time budget of {self.seconds:g} s is spent"
            return True
        return False


def _start(setup: DesignSetup, deadline: float | None = None) -> tuple[torch.Tensor, dict[str, float]]:
    """The method's start heights: flat glass, or the transport design on a receiver of
    ``design_method.transport_resolution`` pixels (heights on the design grid), projected onto the
    printing limits where it breaks one. The transport design is Schwartzburg's outer iterations
    where the light goes from the flat bottom straight to the screen, and the masked transport
    start (framework/reconstruction/starts/transport.py, the whole glass masked) through optical elements.
    The transport's Newton stops at ``deadline`` (a ``time.perf_counter()`` value) if it comes first."""
    method = setup.settings.method
    zeros = torch.zeros(setup.grid.shape, dtype=setup.operator.dtype)
    if method.start == "flat":
        return zeros, {}
    coarse = method.transport_resolution or setup.scene.receiver.resolution
    operator = setup.operator
    target = setup.target
    if coarse != setup.scene.receiver.resolution:
        operator = setup.operator.variant(setup.operator.photons, 0, coarse)
        flat = operator.render(torch.zeros(setup.grid.shape, dtype=operator.dtype)).double()
        target = torch.nn.functional.adaptive_avg_pool2d(target[None], coarse)[0]
        target = target * (float(flat.sum()) / float(target.sum()))  # the same power on the coarse screen
    data = ReconstructionData(target=target, mask=torch.ones(setup.grid.shape, dtype=torch.bool), volume=None,
                              delta=0.0)
    problem = DesignProblem(operator, data, setup.grid, operator.scene, setup.constraints)
    if has_elements(operator):  # the light's own path through the elements (the reconstructions' start)
        start = build_plugin("initial", "transport", {"reach": THROUGH_OPTICS_REACH, "p1": 0.0,
                                                       "p2": setup.constraints.max_height}, "initial")
        found = start(StartRequest(problem, Path.cwd(), deadline))
        d, first = found.d.detach().double().cpu().numpy(), found.metrics
    else:  # flat bottom to screen: Schwartzburg's transport design
        transport = build_plugin("design", "schwartzburg", dict(method.transport), "design_method.transport")(
            problem, zeros)
        transport.deadline = deadline
        result = transport.run(method.transport_iterations)
        d, first = result.d.detach().double().cpu().numpy(), result.history[0].extras
    printable = all(setup.constraints.holds(d).values())
    if not printable:  # the refinement starts printable: its penalty then keeps it near the limits
        d = setup.constraints.project(d)
    return torch.from_numpy(d).to(setup.operator.dtype), {"transport_sites": first["transport_sites"],
                                                          "transport_seconds": first["transport_seconds"],
                                                          "transport_converged": first["transport_converged"],
                                                          "transport_max_relative_mass_error":
                                                              first["transport_max_relative_mass_error"],
                                                          "transport_printable": float(printable)}


def _unprojected_relative_l2(problem: Problem, raw: np.ndarray, target: np.ndarray) -> float:
    """The relative L2 of the method's last iterate before the projection onto the limits, by the
    design's operator; NaN where that iterate's print reaches into the optical elements above the
    glass (the transport design alone fits heights beyond the limits, which no operator renders there)."""
    try:
        image = problem.fidelity.evaluate(torch.from_numpy(raw).to(problem.operator.dtype), with_grad=False).image
    except PrintReachesElement:
        return math.nan
    return relative_l2(image.double().numpy(), target)


def _rendered_figures(setup: DesignSetup, d: np.ndarray, exact: Any) -> tuple[np.ndarray, dict[str, float]]:
    image = exact.render(torch.from_numpy(d).to(torch.float64)).detach().double().cpu().numpy()
    target = setup.target.numpy()
    return image, {"relative_l2": relative_l2(image, target), "ssim": ssim(image, target)}


def wall_light(setup: DesignSetup, d: np.ndarray, photons: int, caustic: np.ndarray) -> dict[str, float]:
    """What the substrate's clear side walls add to the independently rendered ``caustic``
    (docs/method.md, "The substrate's side walls"): the share of its light that a wall reflected
    or refracted (the same heights rendered by the exact renderer with absorbing walls, the rest)
    and how well that blackened-edge caustic matches the target. Empty for absorbing walls and
    through optical elements (whose exact references are not wavefront renders)."""
    scene = setup.scene
    if scene.substrate.walls != "clear" or has_elements(setup.operator):
        return {}
    blackened = replace(scene, substrate=replace(scene.substrate, walls="absorbing"))
    renderer = WavefrontRenderer(blackened, vertices=wavefront_vertices(photons, scene.channels))
    image = renderer.render(torch.from_numpy(d).to(torch.float64)).double().numpy()
    total = float(caustic.sum())
    return {"wall_light_share": 1.0 - float(image.sum()) / total if total > 0 else 0.0,
            "blackened_edges_relative_l2": relative_l2(image, setup.target.numpy())}


def run_design(cfg: Mapping[str, Any], output_dir: Path, base_dir: Path | None = None,
               setup: DesignSetup | None = None) -> DesignResult:
    """Design the glass for ``cfg`` into ``output_dir`` (module docstring); resumes from the run
    directory's checkpoint if one is there."""
    setup = setup or prepare_design(cfg, base_dir)
    settings, method = setup.settings, setup.settings.method
    seconds, seed, tracking = settings.seconds, settings.seed, settings.tracking
    output_dir.mkdir(parents=True, exist_ok=True)
    problem = setup.problem
    name, params = split_name(method.solver, "design_method.solver")
    checkpoint = output_dir / CHECKPOINT
    log = plugin_class("tracker", tracking.name, RunLog)
    with log(experiment=tracking.experiment, run_name=method.name, store_dir=tracking.store_dir,
             tracking_uri=tracking.uri, params=settings.params, tags={"method": method.name, "target": setup.source}
             ) as tracker:
        began = time.perf_counter()
        start_metrics: dict[str, float] = {}
        factor = settings.model_noise_factor
        flat_fits = not checkpoint.is_file() and setup.flat_discrepancy <= factor * setup.model_noise
        if checkpoint.is_file() or flat_fits:
            d0 = torch.zeros(setup.grid.shape, dtype=setup.operator.dtype)
        else:
            phase(f"design: the {method.name} start (at most {START_SHARE * seconds:.0f} s)")
            d0, start_metrics = _start(setup, began + START_SHARE * seconds)
        start_seconds = time.perf_counter() - began
        solver = build_plugin("design", name, params, "design_method.solver")(problem, d0)
        if checkpoint.is_file():
            restore(solver, checkpoint)
            start_metrics = json.loads((output_dir / "start.json").read_text())
            start_seconds = float(start_metrics.pop("seconds"))
        else:
            (output_dir / "start.json").write_text(json.dumps({"seconds": start_seconds, **start_metrics}))
        tracker.log_metrics({f"start_{k}": v for k, v in start_metrics.items()} | {"start_seconds": start_seconds})
        history = MetricsHistory()
        at_noise = build_plugin("stopping", "morozov", {"tau_dis": factor}, "design_method.model_noise_factor")
        at_noise.setup(problem)  # the problem's noise level is the model's own, not a photo's
        phase(f"design ({method.name}): refining within the {seconds:.0f} s budget")
        callbacks = [history, ProgressBar(desc=f"design ({method.name})", seconds=seconds - start_seconds),
                     TimeBudget(seconds, start_seconds),
                     at_noise, tracker.metrics_callback(),
                     Checkpointer(checkpoint, every=settings.checkpoint_every)]
        result = solver.run(0 if flat_fits else method.max_iter, callbacks)
        if flat_fits:
            result.stop_reason = "flat glass casts the target to within the operator's own render noise"
        design_seconds = start_seconds + result.elapsed_s
        raw = result.d.detach().double().cpu().numpy()
        phase("design: the nearest printable design")
        heights = setup.constraints.project(raw)
        holds = setup.constraints.holds(heights)
        photons = settings.evaluation_photons or 4 * setup.operator.photons
        phase(f"design: rendering the printable design independently ({photons} photons)")
        exact = setup.operator.exact_variant(photons, seed + 1000, setup.scene.receiver.resolution)
        caustic, figures = _rendered_figures(setup, heights, exact)
        figures.update(wall_light(setup, heights, photons, caustic))
        model = problem.fidelity.evaluate(torch.from_numpy(heights).to(setup.operator.dtype), with_grad=False)
        measured = setup.constraints.measure(heights)
        metrics = {**figures, "model_relative_l2": relative_l2(model.image.double().numpy(), setup.target.numpy()),
                   "unprojected_relative_l2": _unprojected_relative_l2(problem, raw, setup.target.numpy()),
                   "design_seconds": design_seconds, "start_seconds": start_seconds, "iterations": result.iterations,
                   **{f"printed_{k}": v for k, v in measured.items()},
                   **{f"holds_{k}": float(v) for k, v in holds.items()}}
        transport = start_metrics or (result.history[0].extras if result.history else {})
        if "transport_converged" in transport:
            metrics["transport_converged"] = transport["transport_converged"]
            metrics["transport_max_relative_mass_error"] = transport["transport_max_relative_mass_error"]
        if settings.previews:
            phase(f"design: previews at {', '.join(f'{p:g}' for p in settings.previews)} x the screen distance")
        previews = save_previews(setup, heights, photons, output_dir)
        metrics.update(previews)
        verdict = design_verdict(metrics, setup, result.stop_reason)
        _save(output_dir, setup, heights, caustic, metrics, verdict, history)
        tracker.log_metrics(metrics)
        tracker.log_artifacts(output_dir, "design")
    return DesignResult(heights, metrics, verdict)


def design_verdict(metrics: Mapping[str, float], setup: DesignSetup, stop_reason: str) -> list[str]:
    """The run's verdict, one line each: the match, the printing limits, how the run ended."""
    c, mm = setup.constraints, setup.mm
    lines = [f"matches the target to {metrics['relative_l2']:.1%} (relative L2 after energy normalisation), "
             f"SSIM {metrics['ssim']:.2f}, rendered independently of the design's photons (the exact wavefront "
             "renderer, or fresh photons through optical elements), which shares the model's surface and its walls' "
             "optics; the glass as cut, traced ray by ray through glass.stl: python -m experiments.paper.trace_design",
             _edge_line(setup),
             f"max slope {metrics['printed_max_slope']:.3f} within {c.max_slope:g}; heights 0 to "
             f"{metrics['printed_max_height'] * mm:.3f} mm within {c.max_height * mm:.3g} mm"]
    if c.min_feature is not None:
        lines.append(f"smallest crest or valley radius {mm / max(metrics['printed_max_curvature'], 1e-300):.3g} mm, "
                     f"at least {0.5 * c.min_feature * mm:.3g} mm asked")
    if c.volume is not None:
        lines.append(f"volume {metrics['printed_volume'] * mm ** 3:.4g} mm3 (asked {c.volume * mm ** 3:.4g} mm3)")
    if metrics.get("wall_light_share", 0.0) > WALL_LIGHT_NOTED:
        share, blackened = metrics["wall_light_share"], metrics["blackened_edges_relative_l2"]
        line = (f"the substrate's clear side walls send {share:.1%} of the light on the screen (the light entering "
                "next to them, reflected), ")
        if blackened < metrics["relative_l2"]:
            line += (f"which costs the match: with blackened or frosted edges it would be {blackened:.1%}; blacken "
                     "them and design with substrate.walls=absorbing")
        else:
            line += f"designed into the caustic (with blackened or frosted edges it would match to {blackened:.1%})"
        lines.append(line)
    broken = [k[len("holds_"):] for k, v in metrics.items() if k.startswith("holds_") and not v]
    if broken:
        lines.append(f"NOT printable as asked: {', '.join(broken)} exceed their limits")
    lines += setup.notes
    if metrics.get("transport_converged") == 0.0:
        lines.append("the transport's Newton stopped at its time or round limit (half the budget, 1000 rounds) with "
                     f"a cell's mass off by up to {metrics['transport_max_relative_mass_error']:.3g} of its own")
    lines.append(f"designed in {metrics['design_seconds']:.0f} s ({stop_reason})")
    return lines


def _edge_line(setup: DesignSetup) -> str:
    """What the design assumed of the light along the square's edge (docs/design.md, "The glass's edge")."""
    raised = setup.scene.substrate.edge_height * setup.mm
    if raised > 0.0:
        return (f"designed with the light of the whole top and its side walls: a top up to {raised:.3g} mm high "
                "along the square's edge is lit (substrate.edge_height)")
    return ("designed with the light of the substrate's own square (substrate.edge_height=0): right where the "
            "top stays on the substrate along the edge (constraints.edge_margin or mask), else its rim is dark in "
            "the model")


def _save(output_dir: Path, setup: DesignSetup, heights: np.ndarray, caustic: np.ndarray, metrics: Mapping[str, float],
          verdict: list[str], history: MetricsHistory) -> None:
    np.save(output_dir / "height_field.npy", heights)
    np.save(output_dir / "caustic.npy", caustic.astype(np.float32))
    np.save(output_dir / "target.npy", setup.target.numpy().astype(np.float32))
    export_outputs(output_dir, heights, setup.grid.half_width, setup.grid.base, setup.mm, formats=("stl", "obj"),
                   refine=setup.mesh_refine)
    save_design_figure(output_dir / "design.png", setup, heights, caustic, metrics, history)
    (output_dir / "metrics.json").write_text(json.dumps(dict(metrics), indent=2))
    (output_dir / "verdict.txt").write_text("\n".join(verdict) + "\n")
