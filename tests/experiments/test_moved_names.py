"""The old flat names of experiments/ still run for one release (experiments/moved.py), with one
line that names the new module."""

from __future__ import annotations

import subprocess
import sys

from experiments.moved import new_name


def test_every_old_name_maps_to_its_folder() -> None:
    assert new_name("reproduce_table1") == "experiments.paper.reproduce_table1"
    assert new_name("bench") == "experiments.benchmarks.bench"
    assert new_name("reconstruct") == "experiments.apps.reconstruct"
    assert new_name("no_such_script") is None


def test_an_old_name_runs_after_one_line() -> None:
    done = subprocess.run([sys.executable, "-m", "experiments.reproduce_fig4", "--help"], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stderr.splitlines()[0] == ("deprecated: experiments.reproduce_fig4 is now "
                                           "experiments.paper.reproduce_fig4; the old name goes in the next release")
    assert "usage: reproduce_fig4.py" in done.stdout
