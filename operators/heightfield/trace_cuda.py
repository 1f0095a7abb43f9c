"""Host side of the CUDA photon kernels (:mod:`operators.heightfield.kernels_cuda`): image and gradient on the GPU.

The same photons, optics and splat as :class:`operators.heightfield.trace_native.FusedTracer`, one GPU thread
per photon. Arrays are CUDA arrays (torch CUDA tensors or numba device arrays; plain numpy arrays
under numba's CUDA simulator). Nothing per photon is stored, so a launch covers up to LAUNCH
photons whatever the operator's chunk size.
"""

from __future__ import annotations

import logging

import numpy as np
from numba import cuda
from numba.core import config as numba_config

from operators.heightfield.kernels_cuda import THREADS_PER_BLOCK, render_kernel, vjp_kernel
from operators.heightfield.kernels_native import FusedScene
from operators.heightfield.trace_native import FusedTracer

LAUNCH = 1 << 22  # photons per kernel launch: fills any current GPU many times over

# numba's CUDA driver logs every allocation at INFO; under Hydra's INFO root logger that floods the
# run log (seen with sfc-simulate operator.device=cuda).
logging.getLogger("numba.cuda").setLevel(logging.WARNING)


def require_cuda_target() -> None:
    """Refuse numba's deprecated built-in CUDA target (it cannot compile these kernels) and machines
    where numba sees no GPU, naming the fix; numba's CUDA simulator (tests) passes."""
    if getattr(numba_config, "ENABLE_CUDASIM", 0):
        return
    if getattr(cuda, "implementation", "Built-in") != "NVIDIA":
        raise RuntimeError("operator.device=cuda needs NVIDIA's numba-cuda (numba's built-in CUDA target "
                           "cannot compile these kernels): pip install -e '.[cuda]'")
    if not cuda.is_available():
        raise RuntimeError("operator.device=cuda: numba sees no CUDA GPU or driver here; use operator.device=cpu")


class CudaTracer:
    """Runs the photons of ``fused`` (its emitter, scene constants and padding) on the GPU."""

    def __init__(self, fused: FusedTracer) -> None:
        require_cuda_target()
        self.fused = fused
        self.shifts = cuda.to_device(fused.shifts)
        self.indices = cuda.to_device(fused.indices)

    @property
    def gather_pad(self) -> int:
        """Zero border (pixels) that :meth:`vjp` needs around the adjoint image."""
        return self.fused.gather_pad

    @staticmethod
    def launches(start: int, stop: int) -> list[tuple[int, int]]:
        return [(a, min(a + LAUNCH, stop)) for a in range(start, stop, LAUNCH)]

    def render(self, sc: FusedScene, d, start: int, stop: int, image, splat: bool = True) -> float:
        """Add the flux per pixel of photons start .. stop-1 to ``image`` (c, n, n) for float64
        heights ``d`` (m, m) with kernel constants ``sc`` (:meth:`FusedTracer.constants`);
        returns the flux that reached the receiver (W)."""
        reached = 0.0
        for a, b in self.launches(start, stop):
            blocks = (b - a + THREADS_PER_BLOCK - 1) // THREADS_PER_BLOCK
            per_block = cuda.device_array(blocks, dtype=np.float64)
            render_kernel[blocks, THREADS_PER_BLOCK](d, sc, self.shifts, self.indices, a, b, image, per_block,
                                                     splat)
            reached += float(per_block.copy_to_host().sum())
        return reached

    def vjp(self, sc: FusedScene, d, start: int, stop: int, padded, grad) -> None:
        """Add to ``grad`` (m, m) float64 the gradient w.r.t. d of <flux per pixel of photons
        start .. stop-1, G>, ``padded`` = G (c, n, n) float64 with :attr:`gather_pad` zero pixels
        on every side."""
        for a, b in self.launches(start, stop):
            blocks = (b - a + THREADS_PER_BLOCK - 1) // THREADS_PER_BLOCK
            vjp_kernel[blocks, THREADS_PER_BLOCK](d, sc, self.shifts, self.indices, a, b, padded, self.gather_pad,
                                                  grad)
