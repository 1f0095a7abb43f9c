"""Compile the numba gradient kernel in a second process while this one compiles the render kernel.

Only where the numba kernels trace (``operator.kernels: numba``, or no compiled extension: the C
kernels of operators/kernels/heightfield_photons.c need no JIT). Their first run after an install
compiles the fused kernels into numba's on-disk cache, the render kernel and then the gradient
(vjp) kernel, since one process compiles one function at a time (the
time it adds: docs/results.md, "The default run"). :class:`BackgroundCompile` starts
``python -m operators.heightfield.compile_kernels`` when the gradient kernel is not cached yet; that process
compiles it on the second core and writes it to the cache, and :meth:`BackgroundCompile.wait`
holds the caller until it is there, so the caller's first gradient loads it instead of
compiling it again. On every later run the cache is warm and no process is started.
"""

from __future__ import annotations

import subprocess
import sys
from types import TracebackType

COMPILE_MODULE = "operators.heightfield.compile_kernels"  # run as a script: compiles the gradient kernel


def gradient_kernel_cached() -> bool:
    """Whether numba's cache holds a compiled gradient kernel for this source (any CPU, any
    signature: a cheap check of the index file, through numba's internal cache object; False
    when that cannot be read)."""
    from operators.heightfield.adjoint_native import vjp_photons

    try:
        return bool(vjp_photons._cache._cache_file._load_index())
    except Exception:  # noqa: BLE001 - a numba without this internal API: just compile here
        return False


class BackgroundCompile:
    """Context manager: a process compiling the gradient kernel, if it is not cached yet.

    ``wait()`` before the first gradient; leaving the context stops a process still running
    (an interrupted or failed run leaves nothing behind).
    """

    def __init__(self, enabled: bool = True) -> None:
        self.process: subprocess.Popen | None = None
        if enabled and not gradient_kernel_cached():
            self.process = subprocess.Popen([sys.executable, "-m", COMPILE_MODULE],
                                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    @property
    def running(self) -> bool:
        """Whether the compiling process is still at work."""
        return self.process is not None and self.process.poll() is None

    def wait(self) -> None:
        """Block until the background compilation is done (at once if none was started)."""
        if self.process is not None:
            self.process.wait()

    def __enter__(self) -> BackgroundCompile:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait()
