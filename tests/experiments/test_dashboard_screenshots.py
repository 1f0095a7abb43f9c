"""Screenshots of the MLflow dashboard with headless Chromium, on a tiny store made here."""

from __future__ import annotations

import pytest

from experiments.dashboard_screenshots import chromium, metric_charts_url, runs_table_url, take_screenshots
from framework.tracking.mlflow_tracker import MlflowTracker

PNG = b"\x89PNG\r\n\x1a\n"


def _tiny_store(store) -> None:
    for method, rate in (("M1", 0.9), ("M2V1", 0.7)):
        with MlflowTracker("table1", run_name=method, store_dir=store, params={"method": method}) as tracker:
            for k in range(1, 6):
                tracker.log_metrics({"rel_discrepancy": 0.3 * rate**k, "objective": rate**k}, step=k)
            tracker.log_metrics({"rel_error": 0.1 * rate, "iterations": 5, "run_time_s": 1.0}, step=5)


def test_the_ui_pages_are_the_runs_table_and_the_model_metrics():
    assert runs_table_url("http://h:1", "3") == "http://h:1/#/experiments/3/runs?workflowType=machine_learning"
    assert metric_charts_url("http://h:1", "3", "abc") == (
        "http://h:1/#/experiments/3/runs/abc/model-metrics?workflowType=machine_learning")


@pytest.mark.skipif(chromium() is None, reason="no Chromium binary")
def test_screenshots_of_the_runs_table_and_the_metric_charts(tmp_path):
    _tiny_store(tmp_path / "mlruns")
    shots = take_screenshots(f"sqlite:///{tmp_path / 'mlruns' / 'mlflow.db'}", "table1", tmp_path / "images")
    assert [p.name for p in shots] == ["mlflow_runs.png", "mlflow_metrics.png"]
    for shot in shots:
        assert shot.read_bytes()[:8] == PNG and shot.stat().st_size > 5000, shot
