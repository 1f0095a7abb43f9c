"""Test-session settings: parallel workers (pytest-xdist, ``-n auto``) share the machine's cores.

Each of N workers gets cores / N threads for torch and the numba kernels, and the processes a test
starts inherit that through the environment, so two workers on two cores run two threads in all.
"""

from __future__ import annotations

import os

import pytest

from framework.core import registry

_WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))

if _WORKERS > 1:
    _THREADS = max(1, (os.cpu_count() or 1) // _WORKERS)
    for _key in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        os.environ[_key] = str(_THREADS)
    import numba
    import torch

    torch.set_num_threads(_THREADS)
    numba.set_num_threads(min(_THREADS, numba.config.NUMBA_NUM_THREADS))


# Tests that run numba kernels (the mesh-scene operator's numba event kernels, the numba build of
# the height-field kernels, the numba splat, the torch reference path's hit search, the wavefront
# renderer's numba tracer, the height-field forward pass), matched on their node ids. In a fresh
# environment each kernel compiles once per process (the mesh kernels take about 2 min, the
# height-field gradient kernel about 1.5 min): under ``-n auto`` one worker runs all of them
# (xdist's loadgroup), so each compiles once and the others load it from numba's cache. A test
# missing here still passes; it only compiles on another worker.
NUMBA_KERNEL_TESTS = (
    "tests/operators/test_compiled_kernels.py", "tests/operators/test_fused.py",
    "tests/operators/test_splat.py", "tests/operators/test_simd.py", "tests/operators/test_heightfield_hit.py",
    "tests/operators/test_flat_slab.py", "tests/operators/test_gradients.py", "tests/operators/test_photon_paths.py",
    "tests/operators/test_wavefront.py", "tests/operators/test_precompile.py", "tests/framework/test_starts.py",
    "tests/operators/test_side_walls.py", "tests/operators/test_flank_bound.py", "tests/operators/test_jvp.py",
    "tests/experiments/test_compile_kernels.py",
    "tests/experiments/test_bench.py",
    # the mesh-scene operator with its numba event kernels (its other tests trace with the C kernels)
    "-numba]",
    "under_a_disc[numba]",  # tests/operators/test_extended_light.py: the numba kernels under a disc
)
# Files whose tests share a module-scoped fixture that takes seconds (renders, photos): one worker
# runs each, so that the fixture is built once.
SHARED_FIXTURE_FILES = ("tests/experiments/test_run_report.py", "tests/operators/test_irradiance_model.py",
                        "tests/operators/test_paraboloid_focus.py")


def pytest_collection_modifyitems(config, items) -> None:
    for item in items:
        path = item.nodeid.split("::")[0]
        if any(key in item.nodeid for key in NUMBA_KERNEL_TESTS):
            item.add_marker(pytest.mark.xdist_group("numba_kernels"))
        elif path in SHARED_FIXTURE_FILES:
            item.add_marker(pytest.mark.xdist_group(path))


@pytest.fixture
def own_registrations(monkeypatch):
    """Registrations made in a test are forgotten after it."""
    monkeypatch.setattr(registry, "_registered", {kind: dict(found) for kind, found in registry._registered.items()})
