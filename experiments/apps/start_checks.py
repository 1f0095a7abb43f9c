"""Checks Hydra itself needs before a run or a sweep starts (conf/reconstruct.yaml,
``hydra.callbacks``), each ending in one ``error:`` line and exit status 1:

- the run or sweep directory must be creatable (Hydra creates it before the task runs);
- a multirun checks every job before the first one starts: a sweep with one bad value refuses to
  start instead of running the jobs before it and dropping the ones after it. Each job's config is
  composed from the sweep's overrides, its plugins built and the checks a single run makes before
  it opens run (framework/reconstruction/reconstruction.py, ``Reconstruction.check``): no render, no MLflow run;
- a launcher whose engine is not there is refused (``hydra/launcher=slurm`` without SLURM, Ray or
  joblib not installed).
"""

from __future__ import annotations

import importlib.util
import os
import shutil
from pathlib import Path
from typing import Any

from hydra import compose
from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from experiments.apps.input_errors import INPUT_ERRORS, TRACEBACK_VARIABLE, one_line
from framework.reconstruction.parts import Reconstruction
from framework.files.paths import check_creatable_directory
from experiments.apps.configs import to_plain

__all__ = ["CheckBeforeStart", "check_launcher", "sweep_jobs"]

# Launcher target (a substring of hydra.launcher._target_) -> (what it needs, how to test for it).
ENGINES = {
    "SlurmLauncher": ("SLURM (the sbatch command)", lambda: shutil.which("sbatch") is not None),
    "RayLauncher": ("Ray (pip install -e \".[ray]\")", lambda: importlib.util.find_spec("ray") is not None),
    "JoblibLauncher": ("joblib's launcher (pip install -e \".[parallel]\")",
                       lambda: importlib.util.find_spec("hydra_plugins.hydra_joblib_launcher") is not None),
}


def check_launcher(target: str) -> None:
    """Refuse a launcher whose engine is absent on this machine, naming it and the fix."""
    for name, (needs, present) in ENGINES.items():
        if name in target and not present():
            raise ValueError(f"hydra/launcher ({target.rsplit('.', 1)[-1]}) needs {needs}, which this machine lacks; "
                             "run the sweep where it is, or choose hydra/launcher=parallel or basic")


def sweep_jobs(task_overrides: list[str]) -> list[list[str]]:
    """The override lists of the sweep's jobs, in the order the basic sweeper runs them."""
    parsed = OverridesParser.create().parse_overrides(task_overrides)
    return [job for batch in BasicSweeper.split_arguments(parsed, None) for job in batch]


def _refuse(error: Exception) -> None:
    """End the program in the error's one line (or re-raise it with SFC_TRACEBACK=1)."""
    if os.environ.get(TRACEBACK_VARIABLE) == "1":
        raise error
    raise SystemExit(f"error: {one_line(error)} ({TRACEBACK_VARIABLE}=1 shows the traceback)") from None


class CheckBeforeStart(Callback):
    """Check the run directory before a run, and the sweep directory, the launcher and every job
    before a multirun's first job starts."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:  # noqa: D102
        try:
            check_creatable_directory(Path(str(config.hydra.run.dir)), "hydra.run.dir")
        except INPUT_ERRORS as error:
            _refuse(error)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:  # noqa: D102
        try:
            check_creatable_directory(Path(str(config.hydra.sweep.dir)), "hydra.sweep.dir")
            check_launcher(str(config.hydra.launcher.get("_target_", "")))
            base_dir = Path(config.hydra.runtime.cwd)
            jobs = sweep_jobs(list(config.hydra.overrides.task))
            for number, overrides in enumerate(jobs):
                job_cfg = compose(config_name=config.hydra.job.config_name, overrides=overrides)
                try:
                    parts = Reconstruction.from_config(to_plain(job_cfg), base_dir)
                    parts.check(base_dir, Path(config.hydra.sweep.dir) / str(number))
                except INPUT_ERRORS as error:
                    raise type(error)(f"sweep job {number} ({' '.join(overrides) or 'no overrides'}): "
                                      f"{one_line(error)}; no job was started") from None
        except INPUT_ERRORS as error:
            _refuse(error)
