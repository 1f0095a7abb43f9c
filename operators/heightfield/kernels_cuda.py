"""CUDA kernels of the fused photon path: one GPU thread per photon.

They run the very per-photon functions of the CPU kernels (:mod:`operators.heightfield.kernels_native`:
emission, hit search, optics with differentials, footprint, splat adjoint gather), which numba
compiles a second time for the GPU. Only the writes differ: photons of all threads share one
image and one gradient, so the splat and the scatter into the 16 heights around a hit are atomic
adds, and the splat takes its energy-conserving normaliser in a first pass over the footprint
instead of buffering the weights.
"""

from __future__ import annotations

from numba import cuda, float64

from operators.heightfield.adjoint_native import photon_vjp
from operators.heightfield.catmull_rom import clamped_node
from operators.heightfield.kernels_native import trace_photon
from operators.splat.native import falloff, footprint_box, footprint_usable, row_terms

THREADS_PER_BLOCK = 128


@cuda.jit(device=True, inline=True)
def _splat_photon_atomic(img, c, px, py, q00, q01, q11, f) -> None:
    """The splat of :func:`operators.splat.native.splat_photon` (same weights, same normaliser
    over the whole ellipse), added atomically into ``img`` (c, n, n)."""
    if not footprint_usable(f, px, py, q00, q01, q11):
        return
    x0, x1, y0, y1 = footprint_box(px, py, q00, q01, q11)
    s = 0.0
    for iy in range(y0, y1 + 1):
        b, e = row_terms(q01, q11, iy - py)
        rx = x0 - px
        for _ in range(x0, x1 + 1):
            u = max(falloff(q00, rx, b, e), 0.0)
            s += u * u
            rx += 1.0
    if s <= 0.0:
        return
    n = img.shape[1]
    scale = f / s
    for iy in range(max(y0, 0), min(y1, n - 1) + 1):
        b, e = row_terms(q01, q11, iy - py)
        for ix in range(max(x0, 0), min(x1, n - 1) + 1):
            u = falloff(q00, ix - px, b, e)
            if u > 0.0:
                cuda.atomic.add(img, (c, iy, ix), scale * u * u)


@cuda.jit(cache=True)
def render_kernel(d, sc, shifts, indices, start, stop, img, reached, splat):
    """Photons start .. stop-1 (one per thread) splatted into ``img`` (c, n, n) (flux per pixel);
    ``reached`` (blocks,) gets each block's flux that reached the receiver. Arguments as
    :func:`operators.heightfield.kernels_native.render_photons`; THREADS_PER_BLOCK threads per block."""
    flux_sum = cuda.shared.array(THREADS_PER_BLOCK, float64)
    tid = cuda.threadIdx.x
    index = start + cuda.grid(1)
    flux = 0.0
    if index < stop:
        c, px, py, q00, q01, q11, flux = trace_photon(d, sc, shifts, indices, index)
        if splat:
            _splat_photon_atomic(img, c, px, py, q00, q01, q11, flux)
    flux_sum[tid] = flux
    cuda.syncthreads()
    step = THREADS_PER_BLOCK // 2
    while step > 0:
        if tid < step:
            flux_sum[tid] += flux_sum[tid + step]
        cuda.syncthreads()
        step //= 2
    if tid == 0:
        reached[cuda.blockIdx.x] = flux_sum[0]


@cuda.jit(cache=True)
def vjp_kernel(d, sc, shifts, indices, start, stop, padded, pad, grad):
    """Add to ``grad`` (m, m) the gradient w.r.t. d of <splat of photons start .. stop-1, G>
    (one photon per thread), arguments as :func:`operators.heightfield.adjoint_native.vjp_photons`."""
    index = start + cuda.grid(1)
    if index >= stop:
        return
    wx = cuda.local.array((4, 4), float64)
    wy = cuda.local.array((4, 4), float64)
    patch = cuda.local.array((4, 4), float64)
    contributes, ix, iy = photon_vjp(d, sc, shifts, indices, index, padded, pad, wx, wy, patch)
    if contributes:
        m = grad.shape[0]
        for a in range(4):
            r = clamped_node(iy - 1 + a, m)
            for b in range(4):
                cuda.atomic.add(grad, (r, clamped_node(ix - 1 + b, m)), patch[a, b])
