"""The CUDA kernels against the CPU fused kernels, photon for photon.

Without a GPU they run under numba's CUDA simulator (a child process with NUMBA_ENABLE_CUDASIM=1,
which must be set before numba.cuda is imported), with the JIT off so that the kernels and the
CPU kernels they are compared with both run as plain Python (seconds, instead of minutes of
compiling entry points no other test uses): that checks the kernels' own code (thread indexing,
the two-pass atomic splat, the block reduction of the reached flux, the atomic scatter of the
gradient) against the CPU loops. On a machine with CUDA the operator with ``device: cuda`` is also
compared with the CPU operator at a realistic photon count.
"""

from __future__ import annotations

import dataclasses

import pytest
import torch

from operators.heightfield.operator import CausticOperator
from operators.scene import Light
from tests.operators.conftest import make_operator
from tests.operators.test_fused import smooth_random_heights
from tests.python_subprocess import run_json_script

SIMULATED = """
import json
import numpy as np
from operators.heightfield.trace_cuda import CudaTracer
from tests.operators.conftest import make_operator
from tests.operators.test_fused import smooth_random_heights

op = make_operator(photons=700, resolution=24, wavelengths=(0.45, 0.65), fresnel=True, footprint_px=1.5)
d = smooth_random_heights().numpy()
sc = op.fused.constants(d)
cpu_image = op.fused.image_buffers(np.dtype("float64"))
cpu_reached = op.fused.render(d, 0, op.photons, cpu_image)
cpu_image = cpu_image.sum(axis=0)
gpu = CudaTracer(op.fused)
gpu_image = np.zeros(op.output_shape)
gpu_reached = gpu.render(sc, d, 0, op.photons, gpu_image)

g = np.random.default_rng(1).normal(size=op.output_shape)
padded = op.fused.pad_gradient(g)
cpu_grad = np.zeros((op.fused.image_buffers(np.dtype("float64")).shape[0], *d.shape))
op.fused.vjp(d, 0, op.photons, padded, cpu_grad)
cpu_grad = cpu_grad.sum(axis=0)
gpu_grad = np.zeros(d.shape)
gpu.vjp(sc, d, 0, op.photons, padded, gpu_grad)
print(json.dumps({
    "reached": [cpu_reached, gpu_reached],
    "image_total": float(cpu_image.sum()),
    "image_max_diff": float(np.abs(gpu_image - cpu_image).max() / np.abs(cpu_image).max()),
    "grad_norm": float(np.linalg.norm(cpu_grad)),
    "grad_max_diff": float(np.abs(gpu_grad - cpu_grad).max() / np.abs(cpu_grad).max()),
}))
"""


@pytest.mark.slow
def test_simulated_cuda_kernels_match_the_cpu_kernels():
    result = run_json_script(SIMULATED, NUMBA_ENABLE_CUDASIM="1", NUMBA_DISABLE_JIT="1")
    cpu_reached, gpu_reached = result["reached"]
    assert cpu_reached > 0 and gpu_reached == pytest.approx(cpu_reached, rel=1e-12)
    assert result["image_total"] > 0.5 * cpu_reached  # most footprints land on the receiver
    assert result["image_max_diff"] < 1e-12
    assert result["grad_norm"] > 0
    assert result["grad_max_diff"] < 1e-10


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_cuda_operator_matches_the_cpu_operator():
    cpu = make_operator(photons=1 << 20, resolution=128, wavelengths=(0.45, 0.65), fresnel=True)
    gpu = make_operator(photons=1 << 20, resolution=128, wavelengths=(0.45, 0.65), fresnel=True, device="cuda")
    heights = smooth_random_heights(m=64)
    cpu_image, gpu_image = cpu.render(heights), gpu.render(heights.cuda())
    assert gpu_image.is_cuda
    assert torch.allclose(gpu_image.cpu(), cpu_image, rtol=1e-9, atol=1e-9 * float(cpu_image.max()))
    g = torch.randn(cpu.output_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    cpu_grad, gpu_grad = cpu.vjp(heights, g), gpu.vjp(heights.cuda(), g.cuda())
    assert torch.allclose(gpu_grad.cpu(), cpu_grad, rtol=1e-8, atol=1e-8 * float(cpu_grad.abs().max()))


def test_cuda_target_check_names_the_fix():
    """Without NVIDIA's numba-cuda, or without a GPU, building the CUDA tracer fails with the fix."""
    from numba import cuda

    from operators.heightfield.trace_cuda import require_cuda_target
    if getattr(cuda, "implementation", "Built-in") != "NVIDIA":
        with pytest.raises(RuntimeError, match=r"pip install -e '\.\[cuda\]'"):
            require_cuda_target()
    elif not cuda.is_available():
        with pytest.raises(RuntimeError, match="operator.device=cpu"):
            require_cuda_target()
    else:
        require_cuda_target()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_cuda_operator_matches_the_cpu_operator_under_a_disc():
    """An extended light's stretches of photons, each launched with its emission point as the light."""
    cpu = make_operator(photons=1 << 20, resolution=128)
    scene = dataclasses.replace(cpu.scene, light=Light(shape="disc", size=2.0, points=64))
    cpu = CausticOperator(scene, cpu.settings)
    gpu = CausticOperator(scene, dataclasses.replace(cpu.settings, device="cuda"))
    heights = smooth_random_heights(m=64)
    cpu_image, gpu_image = cpu.render(heights), gpu.render(heights.cuda())
    assert torch.allclose(gpu_image.cpu(), cpu_image, rtol=1e-9, atol=1e-9 * float(cpu_image.max()))
    g = torch.randn(cpu.output_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    cpu_grad, gpu_grad = cpu.vjp(heights, g), gpu.vjp(heights.cuda(), g.cuda())
    assert torch.allclose(gpu_grad.cpu(), cpu_grad, rtol=1e-8, atol=1e-8 * float(cpu_grad.abs().max()))
