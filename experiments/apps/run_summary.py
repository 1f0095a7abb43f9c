"""The few lines a command prints when a run ends: what was done, how well, how long, where the
files are. Every figure stays in metrics.json (``print_metrics=true`` prints it too)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

SUMMARY_LINES = 5  # at most this many lines, after the verdict lines the run printed itself


def _number(metrics: Mapping[str, Any], key: str) -> float | None:
    value = metrics.get(key)
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


def reconstruction_summary(metrics: Mapping[str, Any], output_dir: Path) -> list[str]:
    """At most SUMMARY_LINES lines on a finished reconstruction (``metrics`` as written to
    metrics.json): method, start, iterations and seconds; the fit and, with a known truth, the
    error; the deviation from the design where there is one; the output directory."""
    start = f" from the {metrics['start']} start" if metrics.get("start") else ""
    seconds = _number(metrics, "run_time_s")
    cost = f" ({metrics['renders']} renders, {metrics['photon_traces'] / 1e6:.1f} M photon-traces)" \
        if "renders" in metrics and "photon_traces" in metrics else ""
    lines = [f"{metrics.get('method', 'reconstruction')}{start}: {metrics.get('iterations', 0)} iterations"
             + (f" in {seconds:.1f} s" if seconds is not None else "") + cost]
    fit = []
    ratio = _number(metrics, "discrepancy_over_delta")
    if ratio is not None:
        fit.append(f"discrepancy {ratio:.2f} x the noise level")
    error = _number(metrics, "rel_error")
    if error is not None:
        fit.append(f"relative height error {error:.4f} against the known truth")
    if fit:
        lines.append("; ".join(fit))
    rms, largest = _number(metrics, "deviation_rms_mm"), _number(metrics, "deviation_max_abs_mm")
    if rms is not None and largest is not None:
        lines.append(f"deviation from the design: rms {rms:.3f} mm, largest {largest:.3f} mm")
    lines.append(f"outputs: {output_dir} (height_field.npy, metrics.json with every figure, figures, checkpoint.pt)")
    return lines
