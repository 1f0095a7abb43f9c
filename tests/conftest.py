"""Test-session settings: parallel workers (pytest-xdist, ``-n auto``) share the machine's cores.

Each of N workers gets cores / N threads for torch and the numba kernels, and the processes a test
starts inherit that through the environment, so two workers on two cores run two threads in all.
"""

from __future__ import annotations

import os

_WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))

if _WORKERS > 1:
    _THREADS = max(1, (os.cpu_count() or 1) // _WORKERS)
    for _key in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        os.environ[_key] = str(_THREADS)
    import numba
    import torch

    torch.set_num_threads(_THREADS)
    numba.set_num_threads(min(_THREADS, numba.config.NUMBA_NUM_THREADS))
