"""One reconstruction, end to end: its parts built by key (framework/reconstruction/parts.py),
then data -> problem -> solver -> outputs, tracked in MLflow.

Used by ``sfc-reconstruct`` (experiments/apps/reconstruct.py); kept here so that the app stays thin
and tests can run a reconstruction without Hydra's command line.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from framework.core.callbacks import Checkpointer, GroundTruthError, MetricsHistory, ProgressBar
from framework.core.checkpoint import resume as resume_solver
from operators.image_operator import ImageOperator
from framework.core.contracts.run_log import RunLog
from framework.core.contracts.stage import Refit, Solve, SolvedRun, StartingRun
from framework.core.contracts.start import Start, StartRequest, StartResult
from framework.core.objective import DataFidelity
from framework.core.problem import Problem
from framework.core.progress import report
from framework.core.solver_loop import Callback, RunResult, returned_iterate
from framework.files.image_io import resolve_path
from framework.reconstruction.coarse_to_fine import coarser_problem, resample_heights
from framework.reconstruction.parts import Reconstruction
from framework.reconstruction.photon_budget import budget_photons, photon_budget
from framework.reconstruction.report_figures import save_reconstruction_figures
from framework.reconstruction.run_checks import CHECKPOINT
from framework.reconstruction.run_outputs import report_verdict, save_outputs
from framework.reconstruction.run_phases import PHASES, PhaseOutcome, resumed_phases
from framework.reconstruction.verdict import volume_report

CALIBRATION_STATE = "calibration.json"
# Refits at most: runs of a start again after one whose calibration moved what the heights absorb.
MAX_REFITS = 2
MLFLOW_RUN = "mlflow_run.json"  # the run's MLflow run id, so that a job resumed in its directory logs into it


def passes(fidelity: DataFidelity) -> dict[str, int]:
    """The operator passes the solvers spent on the data term: forward renders, gradient passes
    and photon-traces (the photons of every pass; a gradient pass traces every photon again)."""
    return {"renders": fidelity.renders, "gradient_passes": fidelity.gradient_passes,
            "photon_traces": fidelity.photon_traces}


def final_operator(parts: Reconstruction, result: RunResult) -> ImageOperator:
    """The operator with the photons of the run's last iteration (framework/reconstruction/photon_budget.py)."""
    photons = result.history[-1].extras.get("photons") if result.history else None
    return parts.operator if photons is None else parts.operator.with_photons(int(photons), parts.settings.seed)


def interrupted_run(output_dir: Path, checkpoint: Path | None, log: type[RunLog], store_dir: Path, uri: str | None
                    ) -> str | None:
    """The logged run's id of the interrupted job whose own checkpoint this run resumes (same run
    directory, same target of the run log ``log``), or None: then a new run starts."""
    record = output_dir / MLFLOW_RUN
    if checkpoint is None or checkpoint != output_dir / CHECKPOINT or not record.is_file():
        return None
    saved = json.loads(record.read_text())
    return saved["run_id"] if saved["tracking_uri"] == log.target_uri(uri, store_dir) else None


def _coarse_levels(parts: Reconstruction, problem: Problem, name: str, start: Start, request: StartRequest
                   ) -> tuple[StartResult, dict[str, float]]:
    """The start, solved on the coarser grids of ``coarse_to_fine`` first (framework/reconstruction/
    coarse_to_fine.py): computed on the coarsest, each level solved by the configured solver and
    stopping rules from the last one's heights, the result resampled to the run's grid (a shaped
    start). Returns it with each level's iterations, discrepancy and seconds
    (``<start>_level<m>_*``); without coarse levels, the start itself."""
    n = int(problem.operator.output_shape[-1])
    levels = parts.coarse_to_fine.resolutions(parts.grid.resolution, n)
    if not levels:
        return start(request), {}
    start_photons, cap = budget_photons(parts, problem.operator)
    coarse = []
    for m_level, n_level in levels:
        share = (n_level / n) ** 2  # the same photons per receiver pixel as the run's
        photons = (max(1, int(start_photons * share)), max(1, int(cap * share)))
        coarse.append((coarser_problem(problem, m_level, n_level, photons[1], parts.settings.seed), photons))
    computed = start(replace(request, problem=coarse[0][0]))  # its data carry the design resampled
    d, shaped, metrics = computed.d.to(problem.operator.dtype), computed.shaped, {}
    schedule_from = None  # the coarsest level: where the solver's own shaped_start_from says
    for level, photons in coarse:
        began, m_level = time.perf_counter(), level.grid.resolution
        solver = parts.make_solver(level, resample_heights(d, m_level))
        if shaped:
            solver.begin_from_shaped_start(schedule_from)
        stopping = parts.fresh_stopping(level)
        budget = photon_budget(parts, level, photons)
        callbacks: list[Callback] = [*stopping, ProgressBar(desc=f"{parts.settings.method} from {name} at {m_level}")]
        result = solver.run(parts.max_iter, [*callbacks, *([budget] if budget else [])])
        d, _ = returned_iterate(result, stopping)
        shaped, schedule_from = True, parts.coarse_to_fine.fine_levels_from
        metrics.update({f"{name}_level{m_level}_iterations": float(result.iterations),
                        f"{name}_level{m_level}_rel_discrepancy": result.history[-1].rel_discrepancy
                        if result.history else float("nan"),
                        f"{name}_level{m_level}_seconds": time.perf_counter() - began})
    return replace(computed, d=resample_heights(d, parts.grid.resolution), shaped=True), metrics


def _solve_from(parts: Reconstruction, problem: Problem, name: str, start: Start, request: StartRequest,
                checkpoint: Path | None, output_dir: Path, tracker: RunLog, steps_before: int,
                truth_error: GroundTruthError | None) -> PhaseOutcome:
    """Run the solver from one start (or continue it from ``checkpoint``) with fresh stopping rules."""
    operator = parts.operator
    began = time.perf_counter()
    start_metrics: dict[str, float] = {}
    if checkpoint is None:  # a resumed run continues from its checkpoint's heights
        computed, level_metrics = _coarse_levels(parts, problem, name, start, request)
        d0, start_metrics = computed.d.to(operator.dtype), {**computed.metrics, **level_metrics}
        if truth_error is not None:  # how far the start itself is from the truth
            start_metrics.update({f"{name}_initial_{k}": v for k, v in truth_error.errors(d0).items()})
        tracker.log_metrics({f"start_{k}": v for k, v in start_metrics.items()}, step=steps_before)
    else:
        d0 = torch.zeros(parts.grid.shape, dtype=operator.dtype)
    shaped = checkpoint is None and computed.shaped
    # heights solved on a coarser grid begin at coarse_to_fine.fine_levels_from
    schedule_from = parts.coarse_to_fine.fine_levels_from if checkpoint is None and level_metrics else None
    for stage in parts.stages if checkpoint is None else ():
        begun = stage.begin(StartingRun(problem, start, d0, shaped, _solve(parts, shaped=False), parts.calibration,
                                        output_dir, parts.settings.seed))
        if begun is not None:
            d0 = begun[0]
            start_metrics.update({f"{name}_{k}": v for k, v in begun[1].items()})
            shaped, schedule_from = True, None
    start_seconds = time.perf_counter() - began
    solver = parts.make_solver(problem, d0)
    if shaped:
        solver.begin_from_shaped_start(schedule_from)
    stopping = parts.fresh_stopping(problem)
    history = MetricsHistory()
    callbacks: list[Callback] = [history, *stopping, ProgressBar(desc=f"{parts.settings.method} from {name}"),
                                 Checkpointer(output_dir / CHECKPOINT, every=parts.settings.checkpoint_every,
                                              run=parts.fingerprint),
                                 tracker.metrics_callback(step_offset=steps_before)]
    budget = photon_budget(parts, problem)
    callbacks += [c for c in (parts.calibration, truth_error, budget) if c is not None]
    if checkpoint is not None:
        print(f"resuming from {checkpoint}", flush=True)
        result = resume_solver(solver, checkpoint, parts.max_iter, callbacks)
    else:
        result = solver.run(parts.max_iter, callbacks)
    d, returned = returned_iterate(result, stopping)
    discrepancy = problem.fidelity.relative_discrepancy(final_operator(parts, result).render(d))
    return PhaseOutcome(name, result, d, returned, discrepancy, history.columns(), time.perf_counter() - began,
                        start_seconds, start_metrics, truth_error.errors(d) if truth_error else {})


def _solve(parts: Reconstruction, shaped: bool) -> Solve:
    """The run's own solver, fresh stopping rules and photon budget on a problem from heights d0
    (a stage's solve, framework/core/contracts/stage.py); ``shaped``: d0 holds the print's shape
    (the solver begins at its finest stage)."""
    def solve(problem: Problem, d0: torch.Tensor, label: str, extra: list[Callback]
              ) -> tuple[torch.Tensor, RunResult]:
        solver = parts.make_solver(problem, d0)
        if shaped:
            solver.begin_from_shaped_start()
        stopping = parts.fresh_stopping(problem)
        budget = photon_budget(parts, problem)
        result = solver.run(parts.max_iter, [*stopping, ProgressBar(desc=f"{parts.settings.method} {label}"),
                                             *([budget] if budget else []), *extra])
        return returned_iterate(result, stopping)[0], result
    return solve


def _refit(parts: Reconstruction, problem: Problem) -> Refit:
    """:func:`_solve` from heights that hold the print's shape, with the discrepancy it reaches and
    whether a stopping rule ended it (the ambiguity check's refit)."""
    def fit(d0: torch.Tensor, label: str) -> tuple[torch.Tensor, float, bool]:
        d, result = _solve(parts, shaped=True)(problem, d0, f"from {label}", [])
        return d, problem.fidelity.relative_discrepancy(problem.operator.render(d)), result.stopped_by != "max_iter"
    return fit


def run_reconstruction(cfg: Mapping[str, Any], output_dir: Path, base_dir: Path,
                       sweep_id: str | None = None) -> dict[str, Any]:
    """Reconstruct the configured scene into ``output_dir``; returns the metrics written to metrics.json."""
    parts = Reconstruction.from_config(cfg, base_dir)
    checkpoint = parts.check(base_dir, output_dir)
    output_dir.mkdir(parents=True, exist_ok=True)
    if parts.settings.compile_in_background:
        with parts.operator.warm_up() as compiling:
            return _reconstruct(parts, output_dir, base_dir, checkpoint, sweep_id, compiling)
    return _reconstruct(parts, output_dir, base_dir, checkpoint, sweep_id, None)


def _run_starts(parts: Reconstruction, problem: Problem, request: StartRequest, output_dir: Path,
                checkpoint: Path | None, tracker: RunLog, truth_error: GroundTruthError | None
                ) -> tuple[list[PhaseOutcome], bool, int]:
    """Run the solver from each of the start's phases in turn (continuing an interrupted run's own
    phase from ``checkpoint``) until one reaches the noise level (a stack with
    ``data.first_fit=lines`` adds one last phase through its stage, framework/stack/stack_stage.py:
    the nearest shot's lines searched from the first candidate these data can run); where that run's calibration
    moved a parameter the heights absorb in part (``JointCalibration.needs_refit``), run its start
    again under the calibrated setup, up to ``MAX_REFITS`` times. Returns the finished runs, whether
    there were several starts, and the MLflow steps used."""
    def lacks_design(start: Start) -> bool:  # a start that reads the design, on data that carry none
        return start.reads_design and problem.data.design is None

    candidates = parts.start.phases()
    runnable = [(name, start) for name, start in candidates if not lacks_design(start)]
    candidates += [added for stage in parts.stages for added in stage.phases(problem, runnable, request)]
    finished, first, refits = resumed_phases(output_dir, checkpoint)
    phases = [*candidates, *((f"{candidates[i][0]}_refit", candidates[i][1]) for i in refits)]
    steps = sum(outcome.result.iterations for outcome in finished)
    index = first - 1
    while index + 1 < len(phases):
        index += 1
        name, start = phases[index]
        if len(candidates) > 1 and lacks_design(start):
            continue  # initial=auto's design candidate (or a search from it): these data have no design
        if len(phases) > 1:  # so that a resumed run knows which start its checkpoint belongs to
            torch.save({"done": [outcome.saved() for outcome in finished], "phase": index, "refits": refits},
                       output_dir / PHASES)
        resume_from = checkpoint if index == first else None
        calibrated = None if parts.calibration is None else parts.calibration.values()
        try:
            outcome = _solve_from(parts, problem, name, start, request, resume_from, output_dir, tracker, steps,
                                  truth_error)
        except ValueError as error:
            if len(phases) == 1:
                raise
            print(f"initial=auto: start {name} left out: {error}", flush=True)
            continue
        finished.append(outcome)
        steps += outcome.result.iterations
        if outcome.result.accepted:
            if calibrated is not None and len(refits) < MAX_REFITS and parts.calibration.needs_refit(calibrated):
                of = index if index < len(candidates) else refits[index - len(candidates)]
                refits.append(of)
                phases.append((f"{candidates[of][0]}_refit", candidates[of][1]))
                print(f"the calibration moved {parts.calibration.describe_move(calibrated)} while the heights "
                      f"absorbed part of it; solving again from start {candidates[of][0]} under the calibrated "
                      "setup", flush=True)
                continue
            break
        if index + 1 < len(phases):
            print(f"start {name} ended short of the noise level ({outcome.result.stop_reason}); "
                  f"trying start {phases[index + 1][0]}", flush=True)
    if not finished:
        raise ValueError("initial=auto: no candidate start could be computed from these data; see the lines above")
    return finished, len(phases) > 1, steps


def _reconstruct(parts: Reconstruction, output_dir: Path, base_dir: Path, checkpoint: Path | None,
                 sweep_id: str | None, compiling: Any) -> dict[str, Any]:
    settings, operator = parts.settings, parts.operator
    method, cfg, tracking = settings.method, settings.cfg, settings.tracking
    store_dir = resolve_path(tracking.store_dir, base_dir)
    with parts.run_log(experiment=tracking.experiment, run_name=cfg.get("method"), store_dir=store_dir,
                       tracking_uri=tracking.uri, params=cfg, tags=settings.tags, sweep_id=sweep_id,
                       continue_run_id=interrupted_run(output_dir, checkpoint, parts.run_log, store_dir,
                                                       tracking.uri)
                       ) as tracker:
        (output_dir / MLFLOW_RUN).write_text(json.dumps({"run_id": tracker.run_id,
                                                         "tracking_uri": tracker.tracking_uri}))
        start = time.perf_counter()
        loaded = parts.data_source.load(parts.data_request(base_dir, output_dir))
        if loaded.design is None and loaded.ground_truth is None and settings.design_given:
            loaded = replace(loaded, design=parts.design(base_dir))  # a measured print's design
        data_seconds = time.perf_counter() - start
        tracker.log_data(loaded, cfg)
        # The truth of synthetic data stays here, for the metrics and the evaluation outputs alone
        # (framework/core/truth.py); everything that shapes the result sees the problem.
        truth, data = loaded.ground_truth, loaded.without_truth()
        problem = Problem(operator, data, parts.grid, parts.scene)
        calibration = parts.calibration
        if calibration is not None:
            resume_from = None if checkpoint is None else checkpoint.parent / CALIBRATION_STATE
            calibration.setup(data.target, data.weights, data.delta, output_dir / CALIBRATION_STATE, resume_from,
                              goal=settings.tau_dis * data.delta)
        truth_error = None if truth is None else GroundTruthError(truth, parts.grid.base)
        if compiling is not None and compiling.running:
            print("waiting for the gradient kernel to compile (first run after an install; cached afterwards)",
                  flush=True)
            compiling.wait()
        request = StartRequest(problem.for_start(), base_dir)
        report(f"reconstruction ({method}): computing the start")
        finished, several, steps = _run_starts(parts, problem, request, output_dir, checkpoint, tracker, truth_error)
        # The last run that reached the noise level (a refit's setup is the calibrated one), else the
        # run that came closest.
        accepted = [o for o in finished if o.result.accepted]
        chosen = accepted[-1] if accepted else min(finished, key=lambda o: o.rel_discrepancy)
        result, d = chosen.result, chosen.d
        solved = SolvedRun(problem, d, result.fitted, _refit(parts, problem), parts.setup.groups.operator_for,
                           settings.mm_per_unit, settings.seed, settings.tau_dis, output_dir)
        for stage in parts.stages:
            revised = stage.revise(solved)
            d = solved.heights = d if revised is None else revised
        final = final_operator(parts, result)
        prediction = final.render(d)
        volume = volume_report(d, data.volume, parts.grid.cell_area)
        start_metrics = {"start": chosen.name, "start_time_s": sum(o.start_seconds for o in finished),
                         **{k: v for o in finished for k, v in o.summary(several).items()}}
        metrics: dict[str, Any] = {
            "method": method, "iterations": result.iterations,
            "returned_iteration": chosen.returned_iteration,
            **result.solver_metrics,
            "stop_reason": result.stop_reason, "stopped_by": result.stopped_by,
            "run_time_s": sum(outcome.seconds for outcome in finished), "data_time_s": data_seconds,
            "rel_discrepancy": problem.fidelity.relative_discrepancy(prediction),
            "delta": data.delta, "intrinsic_noise": data.intrinsic_noise,
            "photons_per_iteration": final.photons, **passes(problem.fidelity),
            **(truth_error.errors(d) if truth_error else {}),
            **volume,
            **start_metrics, **(calibration.report() if calibration else {})}
        metrics.update(save_outputs(output_dir, d, prediction, data, parts.grid, settings.mm_per_unit, truth))
        metrics.update(report_verdict(metrics["rel_discrepancy"], data, settings.tau_dis, chosen.returned_iteration,
                                      result.stop_reason, volume, calibration.never_updated() if calibration else ()))
        solved.prediction = prediction
        for stage in parts.stages:
            added = stage.report(solved)
            metrics.update(added.metrics)
            if added.lines:
                metrics["verdict"] += " " + " ".join(added.lines)
        (output_dir / "metrics.json").write_text(json.dumps(metrics, indent=2))
        save_reconstruction_figures(output_dir, d, problem, prediction, chosen.history, truth)
        tracker.log_metrics({k: float(v) for k, v in metrics.items() if isinstance(v, (int, float)) and v is not None},
                            step=steps)  # the summary (flags as 0/1): last step, not 0
        tracker.set_tags({"stop_reason": result.stop_reason, "stopped_by": result.stopped_by, "start": chosen.name,
                          "verdict": metrics["verdict"]})
        tracker.log_artifacts(output_dir)
    return metrics
