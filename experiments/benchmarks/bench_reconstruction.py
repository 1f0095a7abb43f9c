"""The reconstruction section of sfc-bench: the default ``sfc-reconstruct`` run with today's solver
and with the earlier one (no momentum, every iteration at the configured photons), side by side in
one process, alternating, so that both see the same machine load.

For each: iterations, renders and gradient passes of the data term, photon-traces, renders and
passes (renders + gradient passes) per iteration, the seconds of solving (``run_time_s``: the
starts and the solver, without loading the data) and of the whole run (``wall_s``: with the data,
the outputs and the MLflow logging), the discrepancy and the error against the ground truth. Extra
overrides (e.g. ``experiment=m3v1``) apply to both.
"""

from __future__ import annotations

import contextlib
import sys
import tempfile
import time
from pathlib import Path
from typing import Any
from collections.abc import Sequence

from experiments.apps.configs import reconstruct_config
from framework.reconstruction.reconstruction import run_reconstruction


# The solver before momentum and the photon budget (docs/performance.md, "Fewer photon-traces").
EARLIER_SOLVER = ("solver.momentum_from=null", "photon_budget.start=null")

KEPT = ("iterations", "renders", "gradient_passes", "photon_traces", "photons_per_iteration", "run_time_s",
        "rel_discrepancy", "rel_error", "reached_noise_level", "stopped_by", "start")


def run_once(overrides: Sequence[str], workdir: Path, name: str) -> dict[str, Any]:
    """One reconstruction with ``overrides`` in ``workdir / name`` (its own MLflow store); the
    figures it reports (:data:`KEPT`), renders and passes per iteration."""
    cfg = reconstruct_config([*overrides, f"tracking.store_dir={workdir / 'mlruns'}", "compile_in_background=false"])
    began = time.perf_counter()
    with contextlib.redirect_stdout(sys.stderr):  # the run's verdict lines; stdout carries the JSON report
        metrics = run_reconstruction(cfg, workdir / name, workdir)
    out = {key: metrics.get(key) for key in KEPT}
    out["wall_s"] = time.perf_counter() - began
    iterations = max(metrics["iterations"], 1)
    out["renders_per_iteration"] = metrics["renders"] / iterations
    out["passes_per_iteration"] = (metrics["renders"] + metrics["gradient_passes"]) / iterations
    return out


def reconstruction_report(overrides: Sequence[str] = (), rounds: int = 1) -> dict[str, Any]:
    """Today's default run and the earlier solver's, ``rounds`` times each, alternating which goes
    first; the shorter solving time of each and the ratios."""
    runs: dict[str, list[dict[str, Any]]] = {"now": [], "earlier": []}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(rounds):
            order = ("earlier", "now") if k % 2 == 0 else ("now", "earlier")
            for which in order:
                extra = EARLIER_SOLVER if which == "earlier" else ()
                runs[which].append(run_once([*overrides, *extra], Path(tmp), f"{which}{k}"))
    best = {which: min(r, key=lambda m: m["run_time_s"]) for which, r in runs.items()}
    now, earlier = best["now"], best["earlier"]
    return {
        "overrides": list(overrides), "rounds": rounds, "now": now, "earlier": earlier,
        "speedup": {"solving_time": earlier["run_time_s"] / now["run_time_s"],
                    "photon_traces": earlier["photon_traces"] / now["photon_traces"],
                    "iterations": earlier["iterations"] / now["iterations"]},
    }
