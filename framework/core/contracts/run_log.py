"""The contract of a run's log (kind ``tracker``): where a reconstruction's parameters, metrics per
iteration, data, tags and files go.

The ``tracking`` config group names the plugin (``tracking.name``; the built-in ``mlflow``,
framework/tracking/mlflow_tracker.py) and where it logs (``uri``, or a local ``store_dir``). A
reconstruction (framework/reconstruction/reconstruction.py) checks that target before anything is
built (:meth:`RunLog.check_target`), then opens the log as a context around the run, builds it
with the keywords of :meth:`RunLog.__init__`'s documentation and logs into it; a job resumed in its
run directory reopens the run it started when its target is the same (:meth:`RunLog.target_uri`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import Any

from framework.core.data import ReconstructionData
from framework.core.solver_loop import Callback
from operators.plugin import Plugin

__all__ = ["RunLog"]


class RunLog(Plugin, ABC):
    """One logged run, as a context manager.

    Built as ``cls(experiment=..., run_name=..., store_dir=..., tracking_uri=..., params=...,
    tags=..., sweep_id=..., continue_run_id=...)``: the experiment's name, the run's display name,
    the local store's directory, the target URI (None: the local store), the run's plain config,
    its tags, the multirun it belongs to, and the id of a run to reopen instead of starting one.

    Attributes:
        run_id: The run's id once open (None before).
        tracking_uri: Where it logs.
    """

    run_id: str | None
    tracking_uri: str

    @classmethod
    @abstractmethod
    def check_target(cls, uri: str | None, store_dir: Path) -> None:
        """Refuse, in one line naming the key, a target that cannot take a run (``uri``, or with
        None the local ``store_dir``)."""

    @classmethod
    @abstractmethod
    def target_uri(cls, uri: str | None, store_dir: Path) -> str:
        """The URI a run of these settings logs into (a resumed job compares it with its record)."""

    @abstractmethod
    def __enter__(self) -> RunLog:
        """Open (or reopen) the run."""

    @abstractmethod
    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> bool:
        """Close the run, finished or failed; never swallows the exception."""

    @abstractmethod
    def log_metrics(self, metrics: Mapping[str, float], step: int | None = None) -> None:
        """Numeric metrics at ``step``."""

    @abstractmethod
    def set_tags(self, tags: Mapping[str, Any]) -> None:
        """Run tags (stringified)."""

    @abstractmethod
    def log_data(self, data: ReconstructionData, cfg: Mapping[str, Any]) -> None:
        """The run's input data."""

    @abstractmethod
    def log_artifacts(self, directory: str | Path, artifact_path: str | None = None) -> None:
        """Every file under ``directory`` (the run's outputs)."""

    @abstractmethod
    def metrics_callback(self, every: int = 1, step_offset: int = 0) -> Callback:
        """A solver callback logging every ``every``-th iteration at step ``step_offset`` + iteration."""

