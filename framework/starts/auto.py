"""The start chosen by the data (plugin ``initial/auto``): each candidate start is followed by a
few iterations of the run's own solver, and the candidate whose probe reached the lowest relative
discrepancy starts the run (docs/method.md, "The start")."""

from __future__ import annotations

import time
from pathlib import Path
from collections.abc import Mapping, Sequence
from typing import Any

from framework.plugin_config import as_mapping, build_plugin

from .base import StartRequest, StartResult

__all__ = ["AutoStart"]


class AutoStart:
    """Pick the start by the data. Plugin ``initial/auto``.

    Args:
        candidates: ``{start name: {its config}}``, tried in this order (e.g. ``{zero: {},
            transport: {}}``); not ``auto`` itself.
        probe_iterations: Iterations of the run's solver after each candidate; the lowest relative
            discrepancy among them ranks the candidate. The chosen candidate's start (not its
            probed iterate) starts the run, so a run that keeps flat glass is the plain run.

    A candidate that cannot be computed from these data (a ValueError, e.g. no light within the
    mask's reach) is reported and left out; if none is left the first error is raised.
    """

    name = "auto"

    def __init__(self, candidates: Mapping[str, Any] | None = None, probe_iterations: int = 10) -> None:
        specs = as_mapping(candidates, "initial.candidates")
        if not specs:
            raise ValueError("initial.candidates is empty; give at least one start, e.g. {zero: {}, transport: {}}")
        if "auto" in specs:
            raise ValueError("initial.candidates may not contain auto itself")
        if isinstance(probe_iterations, bool) or not isinstance(probe_iterations, int) or probe_iterations < 1:
            raise ValueError(f"initial.probe_iterations={probe_iterations!r} must be an integer >= 1")
        self.candidates: Sequence[tuple[str, Any]] = [
            (name, build_plugin("initial", name, params, f"initial.candidates.{name}")) for name, params in specs.items()]
        self.probe_iterations = probe_iterations

    def check(self, base_dir: Path) -> None:
        """Each candidate's own check (e.g. a start file exists)."""
        for _, start in self.candidates:
            if callable(getattr(start, "check", None)):
                start.check(base_dir)

    def __call__(self, request: StartRequest) -> StartResult:
        metrics: dict[str, float] = {}
        best: tuple[float, StartResult] | None = None
        first_error: ValueError | None = None
        for name, start in self.candidates:
            began = time.perf_counter()
            try:
                candidate = start(request)
            except ValueError as error:
                print(f"initial=auto: start {name} left out: {error}", flush=True)
                first_error = first_error or error
                continue
            probe = request.make_solver(request.problem, candidate.d).run(self.probe_iterations)
            score = min((r.rel_discrepancy for r in probe.history), default=float("inf"))
            metrics.update({f"auto_{name}_rel_discrepancy": score, f"auto_{name}_seconds": time.perf_counter() - began,
                            **{f"{name}_{key}": value for key, value in candidate.metrics.items()}})
            print(f"initial=auto: start {name}: rel. discrepancy {score:.4f} after {len(probe.history)} iterations",
                  flush=True)
            if best is None or score < best[0]:
                best = (score, candidate)
        if best is None:
            assert first_error is not None
            raise first_error
        chosen = best[1]
        metrics[f"auto_chose_{chosen.name}"] = 1.0
        return StartResult(chosen.d, metrics, chosen.name)
