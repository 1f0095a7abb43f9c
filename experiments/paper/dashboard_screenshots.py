"""Screenshots of the MLflow dashboard (docs/dashboard.md): every metric charted across an experiment's
runs and one run's metric charts, taken with headless Chromium from a local ``mlflow server`` on an
MLflow store, after checking in the rendered page that the UI shows the runs and their metrics.

Example::

    python -m experiments.paper.dashboard_screenshots --store mlruns --experiment fig6 --out docs/images

The MLflow 3 UI remembers per browser whether it shows GenAI or model-training pages; the URLs
ask for the model-training pages (``?workflowType=machine_learning``), so that a fresh browser
shows the runs table rather than the GenAI overview.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from html.parser import HTMLParser
from pathlib import Path

from experiments.apps.mlflow_server import serve

BROWSERS = ("chromium", "chromium-browser", "google-chrome")
WORKFLOW = "workflowType=machine_learning"
WINDOW = (1600, 1000)
# Virtual time before the screenshot. The pages' timers (auto-refresh) run it out fast, in about 6 s of
# real time here; 30 s of it sometimes shot the metric charts before they had fetched their data.
RENDER_BUDGET_MS = 300_000
SHOTS = 3  # renders of a page before a page that lacks its runs or metrics is refused
NAMES = ("mlflow_runs.png", "mlflow_metrics.png")
MAX_RUNS_CHECKED = 20  # the run names a page must show, at most (the newest finished runs)


def chromium() -> str | None:
    """The path of a Chromium (or Chrome) binary, or None."""
    return next((found for name in BROWSERS if (found := shutil.which(name))), None)


def runs_table_url(server: str, experiment_id: str) -> str:
    """The UI page of an experiment's runs table."""
    return f"{server}/#/experiments/{experiment_id}/runs?{WORKFLOW}"


def runs_chart_url(server: str, experiment_id: str) -> str:
    """The UI page that charts every metric across an experiment's runs (one chart per metric, one
    line or point per run), beside the list of runs."""
    return f"{runs_table_url(server, experiment_id)}&compareRunsMode=CHART"


def metric_charts_url(server: str, experiment_id: str, run_id: str) -> str:
    """The UI page of one run's metric charts (each metric against its step, the iteration)."""
    return f"{server}/#/experiments/{experiment_id}/runs/{run_id}/model-metrics?{WORKFLOW}"


def _chromium_command(browser: str, profile: str, window: tuple[int, int]) -> list[str]:
    return [
        browser,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={profile}",
        f"--window-size={window[0]},{window[1]}",
        f"--virtual-time-budget={RENDER_BUDGET_MS}",
    ]


def shoot(browser: str, url: str, out: Path, window: tuple[int, int] = WINDOW) -> str:
    """Save a PNG of ``url`` as headless Chromium renders it in a fresh profile, and return the page's
    document (HTML) after its scripts ran, from the same render."""
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="sfc-chromium-") as profile:
        command = [*_chromium_command(browser, profile, window), "--dump-dom", f"--screenshot={out.resolve()}", url]
        done = subprocess.run(command, capture_output=True, text=True, timeout=180)
    if done.returncode != 0 or not out.is_file():
        raise RuntimeError(f"{browser} could not screenshot {url} (exit {done.returncode}): {done.stderr[-500:]}")
    return done.stdout


class _VisibleText(HTMLParser):
    """The text of a document outside its scripts and styles, one piece per text node."""

    def __init__(self) -> None:
        super().__init__()
        self.pieces: list[str] = []
        self._hidden = 0

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:  # noqa: D102
        self._hidden += tag in ("script", "style", "noscript")

    def handle_endtag(self, tag: str) -> None:  # noqa: D102
        self._hidden -= tag in ("script", "style", "noscript") and self._hidden > 0

    def handle_data(self, data: str) -> None:  # noqa: D102
        if not self._hidden and data.strip():
            self.pieces.append(data.strip())


def visible_text(page: str) -> str:
    """What a rendered page shows as text (its text nodes outside scripts and styles, one per line)."""
    parser = _VisibleText()
    parser.feed(page)
    return "\n".join(parser.pieces)


def check_page(page: str, url: str, names: Sequence[str], any_of: Sequence[str] = ()) -> None:
    """Refuse a rendered page whose text does not show each of ``names`` (the runs) and at least one of
    ``any_of`` (the metrics: the UI draws only the charts in view), each as a word of its own."""
    text = visible_text(page)

    def shown(name: str) -> bool:
        return re.search(rf"(?<![\w.]){re.escape(name)}(?![\w.])", text) is not None

    missing = [name for name in names if not shown(name)]
    if any_of and not any(shown(name) for name in any_of):
        missing.append(f"any of the metrics {', '.join(any_of)}")
    if missing:
        raise RuntimeError(
            f"the MLflow UI at {url} does not show {', '.join(missing)}; it may have no runs, or "
            "the UI's pages moved (see experiments/paper/dashboard_screenshots.py)"
        )


@dataclass(frozen=True)
class Page:
    """A UI page to shoot, the names it must show (the runs) and those it must show one of (metrics)."""

    url: str
    shows: tuple[str, ...]
    shows_one_of: tuple[str, ...]


def pages(server: str, experiment: str, run_name: str | None = None) -> tuple[Page, Page]:
    """The chart of every metric across ``experiment``'s finished runs and the metric charts of its newest
    finished run (named ``run_name`` if given), each with the run names it must show and the metric keys
    it must show one of."""
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=server)
    found = client.get_experiment_by_name(experiment)
    if found is None:
        names = ", ".join(e.name for e in client.search_experiments())
        raise SystemExit(f"error: no experiment {experiment!r} in the store; it has {names} (choose with --experiment)")
    finished = "attributes.status = 'FINISHED'"
    query = finished + (f" and attributes.run_name = '{run_name}'" if run_name else "")
    runs = client.search_runs([found.experiment_id], query, order_by=["attributes.start_time DESC"], max_results=1)
    if not runs:
        what = f"finished run named {run_name!r}" if run_name else "finished run"
        raise SystemExit(f"error: experiment {experiment!r} has no {what} to chart (see --run-name)")
    every = client.search_runs([found.experiment_id], finished, max_results=MAX_RUNS_CHECKED)
    run_names = tuple(sorted({r.info.run_name for r in every}))
    metrics = tuple(sorted(runs[0].data.metrics))
    return (
        Page(runs_chart_url(server, found.experiment_id), run_names, metrics),
        Page(metric_charts_url(server, found.experiment_id, runs[0].info.run_id), (), metrics),
    )


def take_screenshots(
    backend_uri: str, experiment: str, out_dir: Path, run_name: str | None = None, names: tuple[str, str] = NAMES
) -> list[Path]:
    """Serve ``backend_uri`` and save the chart across the runs of ``experiment`` and one run's metric
    charts as PNGs (see :func:`pages`), after checking that the UI shows their runs and metrics."""
    browser = chromium()
    if browser is None:
        raise SystemExit(f"error: no Chromium binary ({', '.join(BROWSERS)}); install one: apt-get install chromium")
    with tempfile.TemporaryDirectory(prefix="sfc-mlflow-ui-") as scratch:
        with serve(backend_uri, Path(scratch) / "artifacts", Path(scratch) / "server.log") as server:
            shots = []
            for page, name in zip(pages(server, experiment, run_name), names):
                print(page.url.replace(server, "<server>"), flush=True)
                for attempt in range(SHOTS):  # on a loaded machine the charts may not have their data yet
                    try:
                        check_page(shoot(browser, page.url, out_dir / name), page.url, page.shows, page.shows_one_of)
                        break
                    except RuntimeError:
                        if attempt == SHOTS - 1:
                            raise
                shots.append(out_dir / name)
            return shots


def main(argv: list[str] | None = None) -> None:
    """Command line: --store (mlruns, its mlflow.db) or --backend-store-uri, --experiment, --run-name, --out."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--store", type=Path, default=Path("mlruns"), help="MLflow store directory (its mlflow.db)")
    parser.add_argument("--backend-store-uri", help="any MLflow backend store URI instead of --store")
    parser.add_argument("--experiment", default="table1", help="experiment name")
    parser.add_argument("--run-name", help="chart the newest finished run of this name (default: the newest)")
    parser.add_argument("--out", type=Path, default=Path("docs/images"), help="directory of the PNGs")
    args = parser.parse_args(argv)
    database = args.store.resolve() / "mlflow.db"
    if args.backend_store_uri is None and not database.is_file():
        raise SystemExit(f"error: no MLflow store {database}; give --store or --backend-store-uri")
    backend = args.backend_store_uri or f"sqlite:///{database}"
    for path in take_screenshots(backend, args.experiment, args.out, args.run_name):
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
