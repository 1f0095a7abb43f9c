"""The MLflow dashboard opened in headless Chromium on a tiny store made here: the pages render the
runs and their metrics, and the screenshots are taken (experiments/paper/dashboard_screenshots.py).

Without a Chromium binary the browser tests skip, unless SFC_REQUIRE_BROWSER=1 (CI sets it, after
installing Debian's chromium), where they fail instead.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

from experiments.paper.dashboard_screenshots import (
    check_page,
    chromium,
    metric_charts_url,
    pages,
    runs_chart_url,
    runs_table_url,
    shoot,
    take_screenshots,
)
from experiments.apps.mlflow_server import serve
from framework.tracking.mlflow_tracker import MlflowTracker

PNG = b"\x89PNG\r\n\x1a\n"
NEEDS_BROWSER = pytest.mark.skipif(
    chromium() is None and os.environ.get("SFC_REQUIRE_BROWSER") != "1", reason="no Chromium binary"
)


def _tiny_store(store) -> None:
    for method, rate in (("M1", 0.9), ("M2V1", 0.7)):
        with MlflowTracker("table1", run_name=method, store_dir=store, params={"method": method}) as tracker:
            for k in range(1, 6):
                tracker.log_metrics({"rel_discrepancy": 0.3 * rate**k, "objective": rate**k}, step=k)
            tracker.log_metrics({"rel_error": 0.1 * rate, "iterations": 5, "run_time_s": 1.0}, step=5)


def test_the_ui_pages_are_the_chart_across_runs_and_the_model_metrics():
    assert runs_table_url("http://h:1", "3") == "http://h:1/#/experiments/3/runs?workflowType=machine_learning"
    assert runs_chart_url("http://h:1", "3") == (
        "http://h:1/#/experiments/3/runs?workflowType=machine_learning&compareRunsMode=CHART"
    )
    assert metric_charts_url("http://h:1", "3", "abc") == (
        "http://h:1/#/experiments/3/runs/abc/model-metrics?workflowType=machine_learning"
    )


def test_a_page_without_the_runs_or_any_metric_is_refused():
    check_page("<div>M1</div><script>M2V1</script><div>rel_error 0.07</div>", "u", ["M1"], ["iterations", "rel_error"])
    with pytest.raises(RuntimeError, match="the MLflow UI at u does not show M1, M2V1;"):
        check_page("<div>M10</div><script>M2V1</script><div>rel_error</div>", "u", ["M1", "M2V1"], ["rel_error"])
    with pytest.raises(RuntimeError, match="does not show any of the metrics iterations, rel_error;"):
        check_page("<div>M1</div><div>rel_errors</div>", "u", ["M1"], ["iterations", "rel_error"])


@NEEDS_BROWSER
def test_the_ui_shows_the_runs_and_their_metrics_and_is_shot(tmp_path):
    _tiny_store(tmp_path / "mlruns")
    shots = take_screenshots(f"sqlite:///{tmp_path / 'mlruns' / 'mlflow.db'}", "table1", tmp_path / "images")
    assert [p.name for p in shots] == ["mlflow_runs.png", "mlflow_metrics.png"]
    for shot in shots:
        assert shot.read_bytes()[:8] == PNG and shot.stat().st_size > 5000, shot


@NEEDS_BROWSER
def test_an_experiment_whose_runs_are_gone_fails_the_check(tmp_path):
    """The check reads the rendered page: once the runs are deleted the UI shows none of them."""
    _tiny_store(tmp_path / "mlruns")
    backend = f"sqlite:///{tmp_path / 'mlruns' / 'mlflow.db'}"
    from mlflow.tracking import MlflowClient

    with tempfile.TemporaryDirectory() as scratch, serve(backend, Path(scratch) / "a", Path(scratch) / "log") as server:
        chart, _ = pages(server, "table1")
        client = MlflowClient(tracking_uri=server)
        for run in client.search_runs([client.get_experiment_by_name("table1").experiment_id]):
            client.delete_run(run.info.run_id)
        with pytest.raises(RuntimeError, match="does not show M1, M2V1"):
            page = shoot(chromium() or "chromium", chart.url, tmp_path / "gone.png")
            check_page(page, chart.url, chart.shows, chart.shows_one_of)
