"""The run's stage that asks which beads the photos leave undecided (framework/tracks/ambiguity.py):
configured by the ``ambiguity`` group, run on a free grid's result when the data carry no design
(a design says how many beads there are), before the outputs are written."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from torch import Tensor

from framework.core.callbacks import ProgressBar
from framework.core.problem import Problem
from framework.core.progress import report
from framework.core.solver_loop import returned_iterate
from framework.lab.calibrated_setup import with_setup
from framework.reconstruction.parts import Reconstruction
from framework.reconstruction.photon_budget import photon_budget
from framework.scene.scene_config import build_operator
from framework.tracks.ambiguity import AmbiguityReport, undecided_beads
from operators.values import checked_number, checked_whole

__all__ = ["AmbiguitySettings", "check_ambiguity"]


@dataclass(frozen=True)
class AmbiguitySettings:
    """``ambiguity.enabled``, the beads between ridges fitted at most and the screen distances (mm) a
    second photo may take."""

    enabled: bool = True
    pairs: int = 1
    screens_mm: tuple[float, ...] = (2.5, 5.0, 10.0, 20.0)

    @classmethod
    def parse(cls, cfg: Mapping[str, Any] | None) -> AmbiguitySettings:
        cfg = dict(cfg or {})
        screens = tuple(checked_number(s, "ambiguity.screens_mm", above=0.0)
                        for s in cfg.get("screens_mm", cls.screens_mm))
        return cls(bool(cfg.get("enabled", True)), checked_whole(cfg.get("pairs", cls.pairs), "ambiguity.pairs", 0),
                   screens)


def _refit(parts: Reconstruction, problem: Problem) -> Callable[[Tensor], tuple[Tensor, float, bool]]:
    """heights -> the run's own solver and stopping rules from them: (the returned heights, their
    discrepancy, whether a stopping rule ended the fit rather than solver.max_iter)."""
    def fit(d0: Tensor) -> tuple[Tensor, float, bool]:
        solver = parts.make_solver(problem, d0)
        solver.begin_from_shaped_start()
        stopping = parts.fresh_stopping(problem)
        budget = photon_budget(parts, problem)
        result = solver.run(parts.max_iter, [*stopping, *([budget] if budget else []),
                                             ProgressBar(desc=f"{parts.settings.method} from one bead between ridges")])
        d, _ = returned_iterate(result, stopping)
        return d, problem.fidelity.relative_discrepancy(problem.operator.render(d)), result.stopped_by != "max_iter"
    return fit


def check_ambiguity(parts: Reconstruction, problem: Problem, d: Tensor, output_dir: Path) -> AmbiguityReport | None:
    """The report (framework/tracks/ambiguity.py) for the run's heights ``d``, None with
    ``ambiguity.enabled`` off; writes each undecided bead's heights as height_field_alternative_<k>.npy."""
    settings = AmbiguitySettings.parse(parts.settings.cfg.get("ambiguity"))
    if not settings.enabled:
        return None
    mm, scene = parts.settings.mm_per_unit, problem.scene
    report("reconstruction: which beads the photos leave undecided")
    began = time.perf_counter()

    def render_at(screen_mm: float) -> Callable[[Tensor], Tensor]:
        moved = with_setup(scene, {"screen_distance": screen_mm / mm})
        return build_operator(parts.settings.cfg, moved, mm=mm).render

    scenes = [problem.shot(i).scene for i in range(len(problem.data.shots))] or [scene]
    screens = [-float(shot.receiver.z) * mm for shot in scenes]
    found = undecided_beads(d, lambda h: problem.fidelity.relative_discrepancy(problem.operator.render(h)),
                            _refit(parts, problem), render_at, parts.settings.tau_dis * problem.data.delta,
                            problem.data.delta, float(problem.grid.half_width), mm, max(screens),
                            settings.screens_mm, settings.pairs)
    found.seconds = time.perf_counter() - began
    undecided = [h for h in found.checked if h.outcome == "undecided"]
    for k, h in enumerate(undecided, 1):
        if h.bead_heights is not None:
            np.save(output_dir / f"height_field_alternative_{k}.npy", h.bead_heights.astype(np.float32))
    return found
