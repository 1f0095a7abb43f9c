"""One line as each job of a multirun starts (a Hydra callback of conf/reconstruct.yaml): its number
of all, its overrides and, where the jobs run one after the other in this process (the basic
launcher, as the paper's reproduction scripts run them), the time the sweep has left at the pace
of its finished jobs."""

from __future__ import annotations

import sys
import time
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from experiments.apps.start_checks import sweep_jobs


class SweepProgress(Callback):
    """Writes ``sweep job k/N (overrides): ..., about T s left`` to stderr as each job starts."""

    def __init__(self) -> None:
        self.total: int | None = None
        self.began = time.perf_counter()
        self.finished = 0

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:  # noqa: D102
        self.total = len(sweep_jobs(list(config.hydra.overrides.task)))
        self.began, self.finished = time.perf_counter(), 0

    def on_job_start(self, config: DictConfig, **kwargs: Any) -> None:  # noqa: D102
        if self.total is None:  # a launcher that runs the job in another process: no sweep to count
            return
        number = int(config.hydra.job.num) + 1
        overrides = " ".join(config.hydra.overrides.task) or "no overrides"
        left = ""
        if self.finished:
            pace = (time.perf_counter() - self.began) / self.finished
            left = f", about {pace * (self.total - self.finished):.0f} s left"
        print(f"sweep job {number}/{self.total} ({overrides}){left}", file=sys.stderr, flush=True)

    def on_job_end(self, config: DictConfig, job_return: Any, **kwargs: Any) -> None:  # noqa: D102
        self.finished += 1
