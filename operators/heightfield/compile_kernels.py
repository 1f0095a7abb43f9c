"""``python -m operators.heightfield.compile_kernels``: compile the gradient kernel into numba's cache.

Started by :class:`operators.heightfield.precompile.BackgroundCompile` in a second process; exits 0 when the
kernel is in the cache afterwards.
"""

from __future__ import annotations

import sys

import torch

from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.heightfield.precompile import gradient_kernel_cached
from operators.scene import Receiver, Scene


def small_numba_operator(dtype: str = "float32") -> CausticOperator:
    """An operator of 64 photons on an 8 x 8 receiver that traces with the numba kernels in
    ``dtype``: its calls compile the kernels with the argument types every operator of that
    precision passes them (the types do not depend on sizes or settings)."""
    return CausticOperator(Scene(receiver=Receiver(resolution=8)),
                           OperatorSettings(photons=64, chunk_size=64, kernels="numba", dtype=dtype))


def compile_gradient_kernel() -> None:
    """Compile (or load) the gradient kernel: one vjp of :func:`small_numba_operator`."""
    op = small_numba_operator()
    op.vjp(torch.zeros(4, 4, dtype=op.dtype), torch.zeros(op.output_shape, dtype=op.dtype))


if __name__ == "__main__":
    compile_gradient_kernel()
    sys.exit(0 if gradient_kernel_cached() else 1)
