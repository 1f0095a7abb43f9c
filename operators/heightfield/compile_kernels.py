"""``python -m operators.heightfield.compile_kernels [--all] [--nice]``: compile numba photon kernels into numba's cache.

Started by :class:`operators.heightfield.precompile.BackgroundCompile` in a second process: the
gradient kernel, or with ``--all`` the render kernel too; ``--nice`` lowers its priority and holds
the compile lock (operators/heightfield/precompile.py) while it works. Exits 0 when the kernels
are in the cache afterwards.
"""

from __future__ import annotations

import fcntl
import os
import sys

import torch

from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.heightfield.precompile import LOCK, gradient_kernel_cached, numba_kernels_cached
from operators.scene import Receiver, Scene


def compile_kernels(render: bool) -> None:
    """Compile (or load) the numba gradient kernel, and the render kernel with ``render``, with the
    argument types every operator passes them: a small operator (the kernels' types do not depend
    on sizes or settings, but for the image's float type: float32, the default)."""
    op = CausticOperator(Scene(receiver=Receiver(resolution=8)),
                         OperatorSettings(photons=64, chunk_size=64, kernels="numba"))
    if render:
        op.render(torch.zeros(4, 4, dtype=op.dtype))
    op.vjp(torch.zeros(4, 4, dtype=op.dtype), torch.zeros(op.output_shape, dtype=op.dtype))


if __name__ == "__main__":
    everything = "--all" in sys.argv[1:]
    if "--nice" in sys.argv[1:]:
        os.nice(10)
        handle = open(LOCK, "a")
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            sys.exit(0)  # another process is compiling them
    compile_kernels(everything)
    sys.exit(0 if (numba_kernels_cached() if everything else gradient_kernel_cached()) else 1)
