"""The line each job of a multirun starts with (experiments/apps/sweep_progress.py)."""

from __future__ import annotations

import re

from omegaconf import OmegaConf

from experiments.apps.sweep_progress import SweepProgress


def _job(num: int, overrides: list[str]) -> object:
    return OmegaConf.create({"hydra": {"job": {"num": num}, "overrides": {"task": overrides}}})


def test_each_job_says_its_number_of_all_and_then_the_time_left(capsys):
    progress = SweepProgress()
    progress.on_multirun_start(_job(0, ["experiment=m1,m2v1,m3v1", "seed=0,1"]))
    progress.on_job_start(_job(0, ["experiment=m1", "seed=0"]))
    assert capsys.readouterr().err == "sweep job 1/6 (experiment=m1 seed=0)\n"
    progress.on_job_end(_job(0, []), None)
    progress.on_job_start(_job(1, ["experiment=m1", "seed=1"]))
    line = capsys.readouterr().err
    assert re.fullmatch(r"sweep job 2/6 \(experiment=m1 seed=1\), about \d+ s left\n", line), line


def test_a_job_in_another_process_says_nothing(capsys):
    SweepProgress().on_job_start(_job(3, ["seed=3"]))  # no multirun start in this process
    assert capsys.readouterr().err == ""
