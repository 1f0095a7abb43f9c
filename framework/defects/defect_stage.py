"""The defect report of a run whose data carry the print's design (docs/method.md, "Defects against
the design"; the parts in framework/defects/), a stage of the run (:class:`DefectStage`,
framework/core/contracts/stage.py).

After the run: the uncertainty of every height sample (framework/defects/information.py), the
evidence a defect needs (:func:`evidence_needed`), then the defects found one after another
(framework/defects/pursuit.py): candidate places where the result leaves the design
(framework/defects/regions.py), sized and named by the defect model that explains the photo best
(framework/defects/fit.py), kept if their evidence is enough. Writes
defects.json, defects.csv, defects.png, defect_sigma_mm.npy; returns ``defects_*`` metrics; prints
``verdict:`` lines.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from framework.core.contracts.stage import RunStage, SolvedRun, StageReport
from framework.core.plugin_config import as_mapping
from framework.core.problem import Problem
from framework.core.progress import report
from framework.scene.run_settings import carries_design
from framework.defects.fit import Defect
from framework.core.pixel_noise import pixel_noise, pixels_used
from framework.defects.information import column_norms, height_uncertainty
from framework.defects.pursuit import Search, find_defects
from framework.defects.report import defect_lines, kind_counts, save_defect_figure, save_defect_table
from operators.values import checked_number, checked_whole

__all__ = ["DefectSettings", "DefectReport", "DefectStage", "evidence_needed", "report_defects"]

ENABLED = ("auto", "on", "off")


@dataclass(frozen=True)
class DefectSettings:
    """The ``defects`` config group (conf/reconstruct.yaml says what each means)."""

    enabled: str = "auto"
    min_deviation: float = 0.02
    z_min: float = 3.0
    grow: float = 2.0
    cluster_mm: float = 1.5
    max_candidates: int = 6
    min_evidence: float = 50.0
    model_error_share: float = 0.1
    probes: int = 8
    photons: int = 131072
    evaluations: int = 40
    tolerance: float = 0.05
    tolerance_mm: float = 0.1
    track_height: float = 0.15
    track_width: float = 0.2
    track_offset_mm: float = 0.3
    min_drop_mm3: float = 0.1

    def within_tolerance(self, defect: Defect) -> bool:
        """Whether a defect is within the print's tolerance: a height or width change of less than
        ``tolerance`` (a fraction), a shift of less than ``tolerance_mm``; interruptions and drops never are."""
        if defect.kind in ("too_low", "too_high", "too_wide", "too_narrow"):
            return abs(defect.size) < self.tolerance
        return defect.kind == "displaced" and defect.size < self.tolerance_mm

    @classmethod
    def parse(cls, spec: Any) -> DefectSettings:
        values = dict(as_mapping(spec or {}, "defects"))
        unknown = set(values) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"defects.{sorted(unknown)[0]} is not a setting; use "
                             f"{', '.join(cls.__dataclass_fields__)}")
        settings = cls(**values)
        if settings.enabled not in ENABLED:
            raise ValueError(f"defects.enabled={settings.enabled!r}; use {' | '.join(ENABLED)}")
        for key in ("min_deviation", "z_min", "grow", "cluster_mm", "min_evidence", "model_error_share"):
            checked_number(getattr(settings, key), f"defects.{key}", above=0.0)
        if settings.grow > settings.z_min:
            raise ValueError(f"defects.grow={settings.grow} exceeds defects.z_min={settings.z_min}; the extent's "
                             "level must not be above the peak's")
        for key in ("max_candidates", "probes", "photons", "evaluations"):
            checked_whole(getattr(settings, key), f"defects.{key}", least=1)
        for key in ("tolerance", "tolerance_mm"):
            checked_number(getattr(settings, key), f"defects.{key}", least=0.0)
        return settings


@dataclass(frozen=True)
class DefectReport:
    """The defects (most evident first), the deviation and its uncertainty (m, m), mm, the
    candidates fitted, the evidence a defect needed (pixel noise variances) and how many defects the
    photo needs that lie within the tolerance (not reported); ``lines``: the report in sentences."""

    defects: list[Defect]
    deviation_mm: np.ndarray
    sigma_mm: np.ndarray
    candidates: int
    evidence_needed: float
    within_tolerance: int
    lines: list[str]

    def metrics(self) -> dict[str, Any]:
        return {**kind_counts(self.defects), "defects_candidates": self.candidates,
                "defects_evidence_needed": self.evidence_needed, "defects_within_tolerance": self.within_tolerance,
                "defects_sigma_median_mm": float(np.median(self.sigma_mm))}


class _Misfit:
    """||F(d) - b||_W^2, the weighted residual sqrt(w) (F(d) - b) and the gradient through a
    renderer of ``photons`` (common random numbers: one seed)."""

    def __init__(self, problem: Problem, photons: int, seed: int) -> None:
        self.operator = problem.operator.variant(photons, seed, problem.operator.output_shape[-1])
        self.render = self.operator.render
        self.target = problem.data.target.double()
        self.root_weights = None if problem.data.weights is None else problem.data.weights.double().sqrt()

    def residual(self, d: torch.Tensor) -> torch.Tensor:
        r = self.render(d).double() - self.target
        return r if self.root_weights is None else self.root_weights * r

    def __call__(self, d: torch.Tensor) -> float:
        return float((self.residual(d) ** 2).sum())

    def gradient(self, d: torch.Tensor) -> torch.Tensor:
        """J^T (2 w (F(d) - b)) (m, m): one adjoint pass."""
        r = self.residual(d)
        image = 2.0 * (r if self.root_weights is None else self.root_weights * r)
        return self.operator.vjp(d, image.to(self.operator.dtype))


def evidence_needed(misfit_d: float, noise: float, pixels: int, settings: DefectSettings) -> float:
    """The misfit (pixel noise variances) a defect must remove: ``min_evidence``, or
    ``model_error_share`` of what the reconstruction leaves beyond the pixel noise (misfit_d / s^2 -
    pixels: the model's own error and its photon noise, which a defect model fitted anywhere absorbs
    a part of) if that is more. Both sides scale as 1 / s^2, so the smallest defect reported does not
    depend on the noise level where the model's error dominates."""
    return max(settings.min_evidence, settings.model_error_share * (misfit_d / noise ** 2 - pixels))


def report_defects(problem: Problem, d: torch.Tensor, settings: DefectSettings, seed: int, mm_per_unit: float,
                   output_dir: Path) -> DefectReport:
    """The defect report of the heights ``d`` (m, m) against ``problem.data.design``, written into
    ``output_dir``."""
    data, grid = problem.data, problem.grid
    if data.design is None:
        raise ValueError("a defect report needs the print's design: give height_field.path with measured data, "
                         "or data.printed with synthetic data")
    dtype = problem.operator.dtype
    design = data.design.to(dtype)
    d = d.to(dtype)
    noise = pixel_noise(data.target, data.delta, data.weights)
    norms = column_norms(problem.operator, d, data.weights, settings.probes, seed + 4000)
    peak = max(float(design.abs().max()), 1e-12)
    sigma = height_uncertainty(norms, noise, peak)
    cell_mm = 2.0 * grid.half_width / (grid.resolution - 1) * mm_per_unit
    deviation = (d - design).double().cpu().numpy()
    mask = data.mask.cpu().numpy()
    floor = settings.min_deviation * peak
    z_map = np.maximum(sigma.double().cpu().numpy(), floor / settings.z_min)
    misfit = _Misfit(problem, settings.photons, seed + 5000)
    at_d = misfit(d)
    needed = evidence_needed(at_d, noise, pixels_used(data.target, data.weights), settings)
    search = Search(settings.z_min, settings.grow, settings.cluster_mm, needed, settings.max_candidates,
                    settings.evaluations, cell_mm, grid.cell_area, mm_per_unit)
    found, tried = find_defects(d, at_d, design, mask, z_map, misfit, noise, search, norms.double().cpu().numpy())
    defects = [defect for defect in found if not settings.within_tolerance(defect)]
    within = len(found) - len(defects)
    found_report = DefectReport(defects, deviation * mm_per_unit, sigma.double().cpu().numpy() * mm_per_unit, tried,
                                needed, within,
                                defect_lines(defects, needed, within, settings.tolerance, settings.tolerance_mm))
    save_defect_table(output_dir, defects, settings, found_report.metrics())
    np.save(output_dir / "defect_sigma_mm.npy", found_report.sigma_mm.astype(np.float32))
    save_defect_figure(output_dir / "defects.png", found_report.deviation_mm,
                       design.double().cpu().numpy() * mm_per_unit, defects, grid.half_width * mm_per_unit, needed)
    for line in found_report.lines:
        print(f"verdict: {line}", flush=True)
    return found_report


class DefectStage(RunStage):
    """The defect report against the design the data carry, after the run's verdict; a stack of
    photos is told that it reads one photo, and a run that fitted beads leaves it to the tracks'
    stage (framework/tracks/track_stage.py)."""

    order = 30

    def __init__(self, settings: DefectSettings) -> None:
        self.settings = settings

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any]) -> DefectStage | None:
        settings = DefectSettings.parse(cfg.get("defects"))
        if settings.enabled == "on" and not carries_design(cfg):
            raise ValueError("defects.enabled=on needs the print's design: give height_field.path (the design) with "
                             "data=file or data=photo, or data.printed with synthetic data; or defects.enabled=auto")
        return None if settings.enabled == "off" else cls(settings)

    def report(self, run: SolvedRun) -> StageReport:
        data = run.problem.data
        if data.design is None or run.beads_fitted:
            return StageReport()
        if data.shots:
            print("no defect report: it reads one photo; reconstruct a single shot for it", flush=True)
            return StageReport()
        report("reconstruction: the defect report against the design")
        found = report_defects(run.problem, run.heights, self.settings, run.seed, run.mm_per_unit, run.output_dir)
        return StageReport(found.metrics(), found.lines)
