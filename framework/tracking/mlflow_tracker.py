"""MLflow tracking of reconstructions: one MLflow run per reconstruction.

:class:`MlflowTracker` is a context manager around one run: it points MLflow at a store (by
default a local SQLite file ``sqlite:///<store_dir>/mlflow.db`` with artefacts in
``<store_dir>/artifacts``), creates or reuses the experiment, starts the run (optionally as a
child of a parent run, or grouped by a ``sweep_id`` tag for Hydra multiruns), logs flattened
parameters and tags, and ends the run as FINISHED, FAILED (exception) or KILLED
(KeyboardInterrupt; the exception is re-raised in both cases). Per-iteration metrics go through
:class:`MlflowMetricsCallback`. It uses ``MlflowClient`` only (no global active run), and mlflow
is imported only inside this module's functions.

Experiments are tagged as custom-model (not GenAI) experiments, every run carries the code
version (git commit, dirty work tree, entry point) as tags, and :meth:`MlflowTracker.log_data`
records the run's input data as an MLflow dataset (framework/tracking/tracking_dataset.py, docs/dashboard.md).

Example::

    with MlflowTracker("print-lines", tags={"method": "M2V1", "scene": "lines"}, params=cfg) as tr:
        result = solver.run(200, [MorozovStopping(0.05, 1.01), tr.metrics_callback()])
        tr.log_artifacts(run_dir)
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from framework.core.contracts.run_log import RunLog
from framework.core.solver_loop import Callback
from framework.tracking.store_template import create_empty_store
from framework.tracking.tracking_dataset import data_dataset
from framework.tracking.tracking_target import check_target, check_tracking_server, local_store_uri
from operators.values import checked_whole

if TYPE_CHECKING:
    from framework.core.data import ReconstructionData
    from framework.core.solver_loop import IterationRecord, IterativeSolver, RunResult

__all__ = ["MlflowTracker", "MlflowMetricsCallback", "flatten_params", "MAX_PARAM_VALUE_LENGTH", "code_version_tags",
           "EXPERIMENT_KIND_TAG", "EXPERIMENT_KIND", "DATASET_CONTEXT"]

# MLflow's limits (mlflow.utils.validation): param values 6000 chars, tag values 8000, keys 250.
MAX_PARAM_VALUE_LENGTH = 6000
MAX_TAG_VALUE_LENGTH = 8000
MAX_KEY_LENGTH = 250
_BATCH = 100  # MLflow's max params/tags per log_batch call
_TRUNCATED = "...[truncated]"

# MLflow 3 records an experiment's kind in this tag (read by its UI, mlflow/server/js): "genai_development"
# opens on traces, "custom_model_development" is the classic machine-learning kind with the runs table.
# The UI of MLflow 3.17 prefers its own GenAI / Model training switch (docs/dashboard.md).
EXPERIMENT_KIND_TAG = "mlflow.experimentKind"
EXPERIMENT_KIND = "custom_model_development"
DATASET_CONTEXT = "reconstruction"  # the runs' input tag mlflow.data.context
GIT_COMMIT_TAG = "mlflow.source.git.commit"
GIT_DIRTY_TAG = "git_dirty"
SOURCE_NAME_TAG = "mlflow.source.name"
SOURCE_TYPE_TAG = "mlflow.source.type"
UNKNOWN = "unknown"
REPO_ROOT = Path(__file__).resolve().parents[2]


def _truncate(text: str, limit: int) -> str:
    return text if len(text) <= limit else text[: limit - len(_TRUNCATED)] + _TRUNCATED


def flatten_params(
    params: Mapping[str, Any], sep: str = ".", max_value_length: int = MAX_PARAM_VALUE_LENGTH
) -> dict[str, str]:
    """Flatten a nested mapping into MLflow params: keys joined with ``sep``, values as strings.

    Lists and other leaves become ``str(value)``; values longer than ``max_value_length`` are
    truncated (ending in "...[truncated]"); a key longer than MLflow's 250 characters is an error.

    Example:
        >>> flatten_params({"solver": {"name": "landweber_pixel", "tau": 0.1}, "seeds": [1, 2]})
        {'solver.name': 'landweber_pixel', 'solver.tau': '0.1', 'seeds': '[1, 2]'}
    """
    out: dict[str, str] = {}

    def walk(node: Mapping[str, Any], prefix: str) -> None:
        for key, value in node.items():
            name = f"{prefix}{sep}{key}" if prefix else str(key)
            if isinstance(value, Mapping) and value:
                walk(value, name)
                continue
            if len(name) > MAX_KEY_LENGTH:
                raise ValueError(
                    f"param key {name[:60]!r}... has {len(name)} characters; MLflow allows {MAX_KEY_LENGTH}"
                )
            out[name] = _truncate(str(value), max_value_length)

    if not isinstance(params, Mapping):
        raise ValueError(f"params must be a mapping (dict or DictConfig), got {type(params).__name__}")
    walk(params, "")
    return out


def _git(root: Path, *args: str) -> str | None:
    """Stripped output of ``git -C root args``; None without git, outside a repository or on any error."""
    try:
        done = subprocess.run(["git", "--no-optional-locks", "-C", str(root), *args], capture_output=True, text=True,
                              timeout=10, check=True)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip()


def entry_point() -> str:
    """The running program: the module of ``python -m`` (e.g. ``experiments.apps.reconstruct``), else the
    script's file name (e.g. ``sfc-reconstruct``), else "unknown"."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    if spec is not None and spec.name:
        return spec.name.removesuffix(".__main__")
    script = sys.argv[0] if sys.argv else ""
    return Path(script).name if script not in ("", "-", "-c") else UNKNOWN  # "-": stdin, "-c": a command


def code_version_tags(root: Path = REPO_ROOT) -> dict[str, str]:
    """Run tags naming the code: the git commit of the repository at ``root``, whether its tracked
    files differ from that commit ("true"/"false") and the entry point; "unknown" where git or the
    repository is absent (e.g. the package installed elsewhere)."""
    toplevel = _git(root, "rev-parse", "--show-toplevel")
    in_repo = toplevel is not None and Path(toplevel).resolve() == root.resolve()
    commit = _git(root, "rev-parse", "HEAD") if in_repo else None
    status = _git(root, "status", "--porcelain", "--untracked-files=no") if in_repo else None
    return {GIT_COMMIT_TAG: commit or UNKNOWN, GIT_DIRTY_TAG: UNKNOWN if status is None else str(bool(status)).lower(),
            SOURCE_NAME_TAG: entry_point(), SOURCE_TYPE_TAG: "LOCAL"}


# Tracking URI schemes MLflow stores take (a URI without a scheme is a local file store).
@contextlib.contextmanager
def _store_lock(store_dir: Path) -> Iterator[None]:
    """An exclusive lock on ``store_dir`` (a file lock, so across processes): the first job that
    opens a new SQLite store creates it (a copy of the empty store, framework/tracking/store_template.py)
    while the others wait, instead of racing."""
    with open(store_dir / ".lock", "w") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


class MlflowTracker(RunLog):
    """One MLflow run as a context manager (the run log ``tracking.name=mlflow``,
    framework/core/contracts/run_log.py).

    Args:
        experiment: Experiment name (created if missing).
        run_name: Display name of the run.
        store_dir: Directory of the default local store (``mlflow.db`` + ``artifacts/``).
        tracking_uri: Overrides the default store, e.g. another ``sqlite:///...`` file or a
            tracking server ``http://host:5000`` (which must answer ``/health`` when the run starts).
        params: Nested parameters (e.g. the resolved config), logged flattened.
        tags: Run tags, e.g. ``{"method": "M2V1", "scene": "print_lines"}`` (added to the code version
            tags of :func:`code_version_tags`, which they override).
        parent_run_id: Make this run a child (nested) run of that run.
        sweep_id: Tag ``sweep_id`` grouping the runs of one multirun.
        continue_run_id: Reopen this existing run instead of starting one (a job resumed in its
            run directory after pre-emption logs into the run it started); its params stay.
    """

    def __init__(
        self,
        experiment: str = "shape-from-caustics",
        run_name: str | None = None,
        store_dir: str | os.PathLike[str] = "mlruns",
        tracking_uri: str | None = None,
        params: Mapping[str, Any] | None = None,
        tags: Mapping[str, Any] | None = None,
        parent_run_id: str | None = None,
        sweep_id: str | None = None,
        continue_run_id: str | None = None,
    ) -> None:
        if not experiment or not isinstance(experiment, str):
            raise ValueError(f"experiment must be a non-empty name, got {experiment!r}")
        self.experiment, self.run_name = experiment, run_name
        self.store_dir = Path(store_dir).resolve()
        self._artifact_location: str | None = None
        if tracking_uri is None:
            tracking_uri = local_store_uri(self.store_dir)
            self._artifact_location = (self.store_dir / "artifacts").as_uri()
        self.tracking_uri = tracking_uri
        self.params = dict(params or {})
        self.tags = {str(k): str(v) for k, v in (tags or {}).items()}
        self.parent_run_id, self.sweep_id = parent_run_id, sweep_id
        self.continue_run_id = continue_run_id
        self.run_id: str | None = None
        self.experiment_id: str | None = None
        self._client: Any = None

    @classmethod
    def check_target(cls, uri: str | None, store_dir: Path) -> None:
        """Refuse, before a run opens, a tracking target that cannot take it
        (framework/tracking/tracking_target.py)."""
        check_target(uri, store_dir)

    @classmethod
    def target_uri(cls, uri: str | None, store_dir: Path) -> str:
        """``uri``, or the local store's in ``store_dir``."""
        return uri or local_store_uri(store_dir)

    # -- lifecycle -----------------------------------------------------------------------------
    def __enter__(self) -> MlflowTracker:
        from mlflow.tracking import MlflowClient
        from mlflow.utils.mlflow_tags import MLFLOW_PARENT_RUN_ID

        check_tracking_server(self.tracking_uri)
        local = self.tracking_uri.startswith("sqlite:")
        if local:
            self.store_dir.mkdir(parents=True, exist_ok=True)
        with _store_lock(self.store_dir) if local else contextlib.nullcontext():
            if self._artifact_location is not None and not (self.store_dir / "mlflow.db").exists():
                create_empty_store(self.store_dir / "mlflow.db", self._artifact_location)
            self._client = MlflowClient(tracking_uri=self.tracking_uri)
            self.experiment_id = self._experiment_id()
        if self.continue_run_id is not None:
            self._client.update_run(self.continue_run_id, status="RUNNING")
            self.run_id = self.continue_run_id
            return self
        tags = {**code_version_tags(), **self.tags}
        if self.parent_run_id:
            tags[MLFLOW_PARENT_RUN_ID] = self.parent_run_id
        if self.sweep_id:
            tags["sweep_id"] = str(self.sweep_id)
        run = self._client.create_run(self.experiment_id, run_name=self.run_name, tags={
            k: _truncate(v, MAX_TAG_VALUE_LENGTH) for k, v in tags.items()
        })
        self.run_id = run.info.run_id
        if self.params:
            self.log_params(self.params)
        return self

    def _experiment_id(self) -> str:
        """The experiment's id: created as a custom-model (not GenAI) experiment, or found and given
        that kind if it has none."""
        from mlflow.exceptions import MlflowException

        exp = self._client.get_experiment_by_name(self.experiment)
        if exp is None:
            try:
                return self._client.create_experiment(self.experiment, artifact_location=self._artifact_location,
                                                      tags={EXPERIMENT_KIND_TAG: EXPERIMENT_KIND})
            except MlflowException:  # created concurrently by another job of the same sweep
                exp = self._client.get_experiment_by_name(self.experiment)
        if EXPERIMENT_KIND_TAG not in exp.tags:
            self._client.set_experiment_tag(exp.experiment_id, EXPERIMENT_KIND_TAG, EXPERIMENT_KIND)
        return exp.experiment_id

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: Any) -> bool:
        if self.run_id is None:
            return False
        if exc_type is None:
            status = "FINISHED"
        elif issubclass(exc_type, KeyboardInterrupt):
            status = "KILLED"
        else:
            status = "FAILED"
        if exc is not None:
            self.set_tags({"error": f"{exc_type.__name__}: {exc}"})
        self._client.set_terminated(self.run_id, status=status)
        return False  # re-raise any exception

    def child(self, run_name: str | None = None, **kwargs: Any) -> MlflowTracker:
        """A tracker for a nested run under this (active) run, in the same store and experiment."""
        self._require_run()
        return MlflowTracker(
            self.experiment, run_name=run_name, store_dir=self.store_dir, tracking_uri=self.tracking_uri,
            parent_run_id=self.run_id, sweep_id=kwargs.pop("sweep_id", self.sweep_id), **kwargs,
        )

    # -- logging -------------------------------------------------------------------------------
    def _require_run(self) -> None:
        if self.run_id is None:
            raise RuntimeError("MlflowTracker has no active run; use it as `with MlflowTracker(...) as tracker:`")

    def log_params(self, params: Mapping[str, Any]) -> None:
        """Log a nested mapping as flattened params (see :func:`flatten_params`)."""
        from mlflow.entities import Param

        self._require_run()
        items = [Param(k, v) for k, v in flatten_params(params).items()]
        for i in range(0, len(items), _BATCH):
            self._client.log_batch(self.run_id, params=items[i : i + _BATCH])

    def set_tags(self, tags: Mapping[str, Any]) -> None:
        """Set run tags (values stringified and truncated to MLflow's limit)."""
        from mlflow.entities import RunTag

        self._require_run()
        items = [RunTag(str(k), _truncate(str(v), MAX_TAG_VALUE_LENGTH)) for k, v in tags.items()]
        for i in range(0, len(items), _BATCH):
            self._client.log_batch(self.run_id, tags=items[i : i + _BATCH])

    def log_metrics(self, metrics: Mapping[str, float], step: int | None = None) -> None:
        """Log numeric metrics (one batch) at ``step``."""
        from mlflow.entities import Metric

        self._require_run()
        now = int(time.time() * 1000)
        items = [Metric(str(k), float(v), now, int(step or 0)) for k, v in metrics.items()]
        for i in range(0, len(items), 1000):
            self._client.log_batch(self.run_id, metrics=items[i : i + 1000])

    def log_data(self, data: ReconstructionData, cfg: Mapping[str, Any]) -> None:
        """Log the run's input data as an MLflow dataset in context "reconstruction" (see
        :func:`data_dataset`)."""
        from mlflow.entities import Dataset, DatasetInput, InputTag
        from mlflow.utils.mlflow_tags import MLFLOW_DATASET_CONTEXT

        self._require_run()
        dataset = Dataset(**data_dataset(data, cfg).to_dict())
        self._client.log_inputs(self.run_id, datasets=[
            DatasetInput(dataset, tags=[InputTag(MLFLOW_DATASET_CONTEXT, DATASET_CONTEXT)])])

    def log_artifact(self, path: str | os.PathLike[str], artifact_path: str | None = None) -> None:
        """Copy one file into the run's artefacts."""
        self._require_run()
        if not Path(path).is_file():
            raise FileNotFoundError(f"artefact {path} does not exist")
        self._client.log_artifact(self.run_id, str(path), artifact_path)

    def log_artifacts(self, directory: str | os.PathLike[str], artifact_path: str | None = None) -> None:
        """Copy all files under ``directory`` (e.g. the run's output dir) into the run's artefacts."""
        self._require_run()
        if not Path(directory).is_dir():
            raise FileNotFoundError(f"artefact directory {directory} does not exist")
        self._client.log_artifacts(self.run_id, str(directory), artifact_path)

    def metrics_callback(self, every: int = 1, step_offset: int = 0) -> MlflowMetricsCallback:
        """A solver callback logging every ``every``-th iteration's record to this run, at step
        ``step_offset`` + iteration (a run from a second start continues the first one's steps)."""
        return MlflowMetricsCallback(self, every=every, step_offset=step_offset)


class MlflowMetricsCallback(Callback):
    """Logs each iteration record (objective, discrepancy, step, time, extras) as metrics at step k.

    At the end it logs ``iterations`` and ``elapsed_s`` and tags ``stop_reason`` / ``stopped_by``.
    Runs after the metric callbacks (order 50) so errors computed by them are logged too.

    Args:
        tracker: An active :class:`MlflowTracker`.
        every: Log when ``iteration % every == 0`` (the last iteration is always logged).
        step_offset: Added to the iteration to give the MLflow step.
    """

    order = 50

    def __init__(self, tracker: MlflowTracker, every: int = 1, step_offset: int = 0) -> None:
        every = checked_whole(every, "every", 1)
        self.tracker, self.every, self.step_offset = tracker, every, int(step_offset)
        self._last_logged = -1

    def on_iteration(self, solver: IterativeSolver, record: IterationRecord) -> None:  # noqa: D102
        if record.iteration % self.every == 0:
            self.tracker.log_metrics(record.metrics(), step=self.step_offset + record.iteration)
            self._last_logged = record.iteration

    def on_end(self, solver: IterativeSolver, result: RunResult) -> None:  # noqa: D102
        last = result.last
        if last is not None and last.iteration != self._last_logged:
            self.tracker.log_metrics(last.metrics(), step=self.step_offset + last.iteration)
        self.tracker.log_metrics({"iterations": result.iterations, "total_elapsed_s": result.elapsed_s},
                                 step=self.step_offset + result.iterations)
        self.tracker.set_tags({"stop_reason": result.stop_reason, "stopped_by": result.stopped_by})
