"""sfc-bench's GPU section (experiments/benchmarks/bench.py, ``--device cuda``): the height-field operator on
the GPU beside the CPU fused path of the same machine in the same run."""

from __future__ import annotations

import numba
import torch

from experiments.benchmarks.timing import best_seconds
from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.scene import Scene

__all__ = ["cuda_report"]


def cuda_report(heights: torch.Tensor, photons: int, grad_photons: int, footprint_px: float,
                chunk_size: int) -> dict[str, object]:
    """Forward and forward+backward photons/s of the operator on the GPU (``device: cuda``), its
    trace/splat split, a gradient with the paper's photon count and the GPU's peak memory, beside
    the CPU fused path of the same machine in the same run."""
    def synced(run):
        def call():
            run()
            torch.cuda.synchronize()
        return call

    def operator(count: int, device: str) -> CausticOperator:
        return CausticOperator(Scene(), OperatorSettings(photons=count, footprint_px=footprint_px,
                                                         chunk_size=chunk_size, device=device))

    gpu_heights = heights.cuda()
    op = operator(photons, "cuda")
    target = op.render(torch.zeros(128, 128, device="cuda"))
    op.loss_and_grad(gpu_heights, target)  # warm up: CUDA compilation
    torch.cuda.synchronize()
    forward_s = best_seconds(synced(lambda: op.render(gpu_heights)), repeats=5)
    gradient_s = best_seconds(synced(lambda: op.loss_and_grad(gpu_heights, target)), repeats=5)
    d = heights.double().numpy()
    d_gpu = gpu_heights.double()
    image = torch.zeros(op.output_shape, device="cuda")
    trace_s = best_seconds(synced(lambda: op.gpu.render(op.fused.constants(d), d_gpu, 0, op.photons, image, False)),
                           repeats=5)
    big = operator(grad_photons, "cuda")
    torch.cuda.reset_peak_memory_stats()
    big_s = best_seconds(synced(lambda: big.loss_and_grad(gpu_heights, target)), repeats=3)
    cpu = operator(photons, "cpu")
    cpu_target = target.cpu()
    cpu.loss_and_grad(heights, cpu_target)  # warm up
    cpu_forward_s = best_seconds(lambda: cpu.render(heights), repeats=2)
    cpu_gradient_s = best_seconds(lambda: cpu.loss_and_grad(heights, cpu_target), repeats=2)
    return {
        "gpu": torch.cuda.get_device_name(), "photons": op.photons,
        "forward_photons_per_s": op.photons / forward_s,
        "forward_backward_photons_per_s": op.photons / gradient_s,
        "forward_split": {"trace_s": trace_s, "splat_s": forward_s - trace_s, "trace_fraction": trace_s / forward_s},
        "gradient_paper_photons": {"photons": big.photons, "seconds": big_s,
                                   "gpu_peak_allocated_mb": torch.cuda.max_memory_allocated() / 2 ** 20},
        "cpu_same_machine": {"threads": numba.get_num_threads(),
                             "forward_photons_per_s": cpu.photons / cpu_forward_s,
                             "forward_backward_photons_per_s": cpu.photons / cpu_gradient_s},
        "speedup_over_cpu": {"forward": cpu_forward_s / forward_s, "forward_backward": cpu_gradient_s / gradient_s},
    }
