"""Compiling the gradient kernel in a second process for the first run after an install."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

import operators.heightfield.precompile as precompile
from operators.heightfield.precompile import BackgroundCompile

# The precompile as BackgroundCompile runs it, reporting the gradient kernel's signatures.
_PRECOMPILE = textwrap.dedent("""
    from operators.heightfield.adjoint_native import vjp_photons
    from operators.heightfield.compile_kernels import compile_gradient_kernel
    compile_gradient_kernel()
    print(sorted(map(str, vjp_photons.signatures)))
""")

# A fresh process that takes a gradient of an operator as sfc-reconstruct builds it (other sizes
# and settings than the precompile's) and reports whether numba loaded the kernel from its cache,
# and the signatures it holds.
_FRESH_GRADIENT = textwrap.dedent("""
    import torch
    from operators.heightfield.operator import CausticOperator, OperatorSettings
    from operators.heightfield.adjoint_native import vjp_photons
    from operators.scene import Receiver, Scene
    op = CausticOperator(Scene(receiver=Receiver(resolution=32)),
                         OperatorSettings(photons=5000, footprint_px=2.0, fresnel=True, dtype="float64",
                                          kernels="numba"))
    op.vjp(torch.rand(16, 16, dtype=torch.float64) * 0.01, torch.rand(op.output_shape, dtype=torch.float64))
    print(sum(vjp_photons.stats.cache_hits.values()), sum(vjp_photons.stats.cache_misses.values()))
    print(sorted(map(str, vjp_photons.signatures)))
""")


def _python(script: str) -> list[str]:
    return subprocess.run([sys.executable, "-c", script], check=True, capture_output=True, text=True,
                          timeout=900).stdout.splitlines()


@pytest.mark.slow
def test_precompiled_gradient_kernel_is_loaded_by_a_later_process():
    # numba's own cache, as a user's: the precompile compiles the kernel there (about 1.5 min on one
    # core) unless another process already has. Either way the later process must load exactly the
    # signature the precompile holds, and compile nothing.
    precompiled = _python(_PRECOMPILE)[-1]
    *_, counts, loaded = _python(_FRESH_GRADIENT)
    hits, misses = map(int, counts.split())
    assert (hits, misses) == (1, 0)
    assert loaded == precompiled


def test_background_compile_starts_only_without_a_cached_kernel_and_stops_with_its_context(monkeypatch):
    monkeypatch.setattr(precompile, "gradient_kernel_cached", lambda: True)
    with BackgroundCompile() as compiling:
        assert compiling.process is None
        compiling.wait()
    monkeypatch.setattr(precompile, "gradient_kernel_cached", lambda: False)
    with BackgroundCompile(enabled=False) as compiling:
        assert compiling.process is None
    with BackgroundCompile() as compiling:
        assert compiling.running
    # Killed on leaving the context, not left running.
    assert not compiling.running and compiling.process.returncode is not None
