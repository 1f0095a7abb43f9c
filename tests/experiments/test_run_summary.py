"""The lines sfc-reconstruct prints when a run ends (experiments/apps/run_summary.py)."""

from __future__ import annotations

from pathlib import Path

from experiments.apps.run_summary import SUMMARY_LINES, reconstruction_summary


def test_the_summary_names_the_run_its_fit_its_error_and_where_the_files_are():
    metrics = {"method": "M2V1", "start": "transport", "iterations": 75, "run_time_s": 13.46, "renders": 139,
               "photon_traces": 75890688, "discrepancy_over_delta": 1.0096, "rel_error": 0.055576,
               "deviation_rms_mm": 0.1647, "deviation_max_abs_mm": 1.9858, "verdict": "..."}
    lines = reconstruction_summary(metrics, Path("/runs/a"))
    assert lines == [
        "M2V1 from the transport start: 75 iterations in 13.5 s (139 renders, 75.9 M photon-traces)",
        "discrepancy 1.01 x the noise level; relative height error 0.0556 against the known truth",
        "deviation from the design: rms 0.165 mm, largest 1.986 mm",
        "outputs: /runs/a (height_field.npy, metrics.json with every figure, figures, checkpoint.pt)"]
    assert len(lines) <= SUMMARY_LINES


def test_a_photo_without_truth_or_design_says_only_what_it_knows():
    lines = reconstruction_summary({"method": "M1", "iterations": 3, "discrepancy_over_delta": float("nan")},
                                   Path("out"))
    assert lines == ["M1: 3 iterations",
                     "outputs: out (height_field.npy, metrics.json with every figure, figures, checkpoint.pt)"]
