"""``sfc-compile-kernels`` (experiments/apps/compile_kernels.py): its groups run, and a wrong group name is
refused in one line."""

from __future__ import annotations

import subprocess
import sys

from experiments.apps import compile_kernels
from operators.heightfield.precompile import gradient_kernel_cached
from tests.python_subprocess import ROOT


def test_a_group_compiles_into_numbas_cache_and_exits_zero():
    # The height-field group leaves the gradient kernel in numba's cache (loaded at once where an
    # earlier process compiled it).
    assert compile_kernels.main(["heightfield", "wavefront"]) == 0
    assert gradient_kernel_cached()


def test_an_unknown_group_is_refused_in_one_line():
    done = subprocess.run(
        [sys.executable, "-m", "experiments.apps.compile_kernels", "lenses"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "unknown kernel group(s) lenses: choose from heightfield, mesh, wavefront, tangent"]
