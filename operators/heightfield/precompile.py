"""Compile the numba photon kernels in a second process, so that no run waits for them.

The C kernels of the compiled extension (operators/kernels/heightfield_photons.c) need no JIT; the
numba kernels (operators/heightfield/kernels_native.py, adjoint_native.py) are faster on CPUs whose
vector units LLVM uses better, but compile for one to two minutes into numba's on-disk cache on
first use. With ``operator.kernels: auto`` a run traces with the C kernels while the numba ones are
not cached yet, and :class:`BackgroundCompile` compiles them meanwhile in a niced second process
that outlives the run (one at a time per machine: a lock file), so later runs take them from the
cache. Where only numba can trace (no extension, or ``kernels: numba``), the process compiles the
gradient kernel while the run compiles the render kernel, and :meth:`BackgroundCompile.wait`
holds the run before its first gradient (the time it adds: docs/results.md, "The default run").
"""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from types import TracebackType

COMPILE_MODULE = "operators.heightfield.compile_kernels"  # run as a script: compiles the numba kernels
LOCK = Path(tempfile.gettempdir()) / f"sfc-compile-{os.getuid()}.lock"  # held by the compiling process


def _cached(kernel) -> bool:
    try:
        return bool(kernel._cache._cache_file._load_index())
    except Exception:  # noqa: BLE001 - a numba without this internal API: count as not cached
        return False


def gradient_kernel_cached() -> bool:
    """Whether numba's cache holds a compiled gradient kernel for this source (any CPU, any
    signature: a cheap check of the index file, through numba's internal cache object)."""
    from operators.heightfield.adjoint_native import vjp_photons

    return _cached(vjp_photons)


def numba_kernels_cached() -> bool:
    """Whether both the render and the gradient kernel are in numba's cache (as above)."""
    from operators.heightfield.kernels_native import render_photons

    return _cached(render_photons) and gradient_kernel_cached()


def compiling_elsewhere() -> bool:
    """Whether another process holds the compile lock (is compiling the kernels now)."""
    with open(LOCK, "a") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return True
        fcntl.flock(handle, fcntl.LOCK_UN)
    return False


class BackgroundCompile:
    """Context manager: a process compiling numba kernels, if they are not cached yet.

    ``blocking`` (the run traces with numba): compiles the gradient kernel; ``wait()`` before
    the first gradient; leaving the context stops a process still running. Not blocking (the
    run traces with the C kernels): compiles both kernels for later runs; ``wait()`` returns at
    once and the process goes on after the context (niced, alone on the machine).
    """

    def __init__(self, enabled: bool = True, blocking: bool = True) -> None:
        self.process: subprocess.Popen | None = None
        self.blocking = blocking
        if not enabled:
            return
        if blocking and not gradient_kernel_cached():
            self.process = subprocess.Popen([sys.executable, "-m", COMPILE_MODULE],
                                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        elif not blocking and not numba_kernels_cached() and not compiling_elsewhere():
            self.process = subprocess.Popen([sys.executable, "-m", COMPILE_MODULE, "--all", "--nice"],
                                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                            start_new_session=True)

    @property
    def running(self) -> bool:
        """Whether a compilation that the run waits for is still at work."""
        return self.blocking and self.process is not None and self.process.poll() is None

    def wait(self) -> None:
        """Block until the gradient kernel is compiled (at once if not blocking or none was started)."""
        if self.blocking and self.process is not None:
            self.process.wait()

    def __enter__(self) -> BackgroundCompile:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        if self.blocking and self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait()
