"""The run's stage that asks which beads the photos leave undecided (framework/tracks/ambiguity.py):
configured by the ``ambiguity`` group, run on a free grid's result when the data carry no design
(a design says how many beads there are) and the solver fitted no beads, before the outputs are
written (a stage of the run: framework/core/contracts/stage.py)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from torch import Tensor

from framework.core.contracts.stage import RunStage, SolvedRun, StageReport
from framework.core.plugin_config import as_mapping
from framework.core.progress import report
from framework.tracks.ambiguity import AmbiguityReport, undecided_beads
from operators.values import checked_flag, checked_number, checked_whole

__all__ = ["AmbiguitySettings", "AmbiguityStage"]


@dataclass(frozen=True)
class AmbiguitySettings:
    """``ambiguity.enabled``, the beads between ridges fitted at most and the screen distances (mm) a
    second photo may take."""

    enabled: bool = True
    pairs: int = 1
    screens_mm: tuple[float, ...] = (2.5, 5.0, 10.0, 20.0)

    @classmethod
    def parse(cls, spec: Any) -> AmbiguitySettings:
        """The ``ambiguity`` group, checked: every bad value is one line naming it."""
        cfg = as_mapping(spec, "ambiguity")
        unknown = sorted(set(cfg) - {"enabled", "pairs", "screens_mm"})
        if unknown:
            raise ValueError(f"unknown key ambiguity.{unknown[0]}; ambiguity takes enabled, pairs, screens_mm")
        screens = cfg.get("screens_mm", cls.screens_mm)
        if not isinstance(screens, (list, tuple)) or not screens:
            raise ValueError(f"ambiguity.screens_mm={screens!r} must be a list of screen distances in mm, "
                             "e.g. [2.5, 5, 10, 20]")
        return cls(checked_flag(cfg.get("enabled", True), "ambiguity.enabled"),
                   checked_whole(cfg.get("pairs", cls.pairs), "ambiguity.pairs", 0),
                   tuple(checked_number(s, f"ambiguity.screens_mm[{i}]", above=0.0) for i, s in enumerate(screens)))


class AmbiguityStage(RunStage):
    """Replaces the run's heights by a bead the photos chose over two ridges; reports every pair the
    photos leave undecided, each such bead written as height_field_alternative_<k>.npy."""

    order = 10

    def __init__(self, settings: AmbiguitySettings) -> None:
        self.settings = settings
        self.found: AmbiguityReport | None = None

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any]) -> AmbiguityStage | None:
        settings = AmbiguitySettings.parse(cfg.get("ambiguity"))
        return cls(settings) if settings.enabled else None

    def revise(self, run: SolvedRun) -> Tensor | None:
        """The heights with the beads the photos chose; None where nothing was checked (data with a
        design, fitted beads)."""
        problem, d = run.problem, run.heights
        if run.beads_fitted or problem.data.design is not None:
            return None
        mm, scene = run.mm_per_unit, problem.scene
        report("reconstruction: which beads the photos leave undecided")
        began = time.perf_counter()

        def render_at(screen_mm: float) -> Callable[[Tensor], Tensor]:
            moved = dataclasses.replace(scene, receiver=dataclasses.replace(scene.receiver, z=-screen_mm / mm))
            return run.operator_for(moved).render

        def refit(d0: Tensor) -> tuple[Tensor, float, bool]:
            return run.refit(d0, "one bead between ridges")

        scenes = [problem.shot(i).scene for i in range(len(problem.data.shots))] or [scene]
        screens = [-float(shot.receiver.z) * mm for shot in scenes]
        found = undecided_beads(d, lambda h: problem.fidelity.relative_discrepancy(problem.operator.render(h)),
                                refit, render_at, run.tau_dis * problem.data.delta, problem.data.delta,
                                float(problem.grid.half_width), mm, max(screens), self.settings.screens_mm,
                                self.settings.pairs)
        found.seconds = time.perf_counter() - began
        undecided = [h for h in found.checked if h.outcome == "undecided"]
        for k, h in enumerate(undecided, 1):
            if h.bead_heights is not None:
                np.save(run.output_dir / f"height_field_alternative_{k}.npy", h.bead_heights.astype(np.float32))
        self.found = found
        return found.heights.to(d)

    def report(self, run: SolvedRun) -> StageReport:
        if self.found is None:
            return StageReport()
        lines = self.found.lines()
        for line in lines:
            print(f"verdict: {line}", flush=True)
        return StageReport(self.found.metrics(), lines)
