"""Host side of the splat and its adjoint gather in C, for photons whose splat arguments another
tracer computed (the mesh scenes' C or numba kernels, the torch reference path): the functions
``sfc_splat_spots`` and ``sfc_gather_spots`` of ``operators/kernels/heightfield_photons.c``, the
height-field kernels' own splat and gather, in the compiled extension
(:mod:`operators.kernels.extension`). The same photons per thread and the same arithmetic as
:func:`operators.splat.native.splat_forward` and :func:`operators.splat.native.splat_backward`,
which stay the fallback where the extension was not built; compiled at install, so that a first
render through lenses does not wait for numba to compile the splat.
"""

from __future__ import annotations

import ctypes

import numpy as np

from operators.kernels import extension
from operators.kernels.simd import AVAILABLE as SIMD_AVAILABLE
from operators.splat.native import FAR_PX

_P = ctypes.c_void_p
_I = ctypes.c_int64
_D = ctypes.c_double

_KERNELS = extension.bind((
    ("sfc_splat_spots", [_P, _P, _P, _P, _I, _P, _I, _I, _I, _I, _I, _I, _D], ctypes.c_int),
    ("sfc_gather_spots", [_P, _P, _P, _P, _I, _P, _I, _I, _I, _I, _D, _P, _P, _P], ctypes.c_int)))
AVAILABLE = _KERNELS.available  # whether the extension holds the C splat and gather


def _inputs(pos: np.ndarray, metric: np.ndarray, flux: np.ndarray, channel: np.ndarray, channels: int
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The photons' arguments as the C kernels read them: float64 (and int64 channels),
    C-contiguous, pos (2, N), metric (3, N), flux and channel (N,); other shapes, and channels
    outside 0 .. channels - 1 (the kernels address the image by them), refused."""
    count = flux.shape[0]
    if pos.shape != (2, count) or metric.shape != (3, count) or channel.shape != (count,):
        raise ValueError(f"pos {pos.shape}, metric {metric.shape} and channel {channel.shape} must be (2, N), (3, N) "
                         f"and (N,) for flux {flux.shape}")
    if count and (channel.min() < 0 or channel.max() >= channels):
        raise ValueError(f"photon channels {channel.min()} .. {channel.max()} must lie in 0 .. {channels - 1}, "
                         f"the image's channels")
    return (np.ascontiguousarray(pos, dtype=np.float64), np.ascontiguousarray(metric, dtype=np.float64),
            np.ascontiguousarray(flux, dtype=np.float64), np.ascontiguousarray(channel, dtype=np.int64))


def splat_spots(pos: np.ndarray, metric: np.ndarray, flux: np.ndarray, channel: np.ndarray, out: np.ndarray,
                capacity: int) -> None:
    """Add the photons (pos (2, N) pixel coordinates, metric (3, N), flux (N,) in W, channel (N,))
    into ``out`` (threads, c, n, n) float32 or float64, thread t's contiguous share of the photons
    into out[t]; footprints of more than ``capacity`` pixels are left out."""
    if out.ndim != 4 or out.shape[2] != out.shape[3] or out.dtype not in (np.float32, np.float64) \
            or not out.flags.c_contiguous:
        raise ValueError(f"the images must be a C-contiguous float32/float64 (threads, c, n, n) array, got "
                         f"{out.dtype} {out.shape}")
    pos, metric, flux, channel = _inputs(pos, metric, flux, channel, out.shape[1])
    status = _KERNELS.function("sfc_splat_spots")(
        pos.ctypes.data, metric.ctypes.data, flux.ctypes.data, channel.ctypes.data, flux.shape[0], out.ctypes.data,
        int(out.dtype == np.float32), out.shape[0], out.shape[1], out.shape[2], int(capacity), int(SIMD_AVAILABLE),
        FAR_PX)
    if status != 0:
        raise MemoryError("the C splat could not allocate its buffers or start its threads")


def gather_spots(pos: np.ndarray, metric: np.ndarray, flux: np.ndarray, channel: np.ndarray, padded: np.ndarray,
                 pad: int, threads: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gradients of <G, splat(...)> w.r.t. pos (2, N), metric (3, N) and flux (N,), float64, on
    ``threads`` threads; ``padded`` is G (c, n, n) float64 with ``pad`` zero pixels on every side
    (:func:`operators.splat.native.pad_for_gather`)."""
    if padded.ndim != 3 or padded.shape[1] != padded.shape[2] or padded.shape[1] <= 2 * pad \
            or padded.dtype != np.float64 or not padded.flags.c_contiguous:
        raise ValueError(f"the padded adjoint image must be a C-contiguous float64 (c, n + 2 pad, n + 2 pad) array "
                         f"with pad = {pad}, got {padded.dtype} {padded.shape}")
    pos, metric, flux, channel = _inputs(pos, metric, flux, channel, padded.shape[0])
    g_pos, g_metric, g_flux = np.empty_like(pos), np.empty_like(metric), np.empty_like(flux)
    status = _KERNELS.function("sfc_gather_spots")(
        pos.ctypes.data, metric.ctypes.data, flux.ctypes.data, channel.ctypes.data, flux.shape[0], padded.ctypes.data,
        padded.shape[1] - 2 * pad, int(pad), max(1, int(threads)), int(SIMD_AVAILABLE), FAR_PX, g_pos.ctypes.data,
        g_metric.ctypes.data, g_flux.ctypes.data)
    if status != 0:
        raise MemoryError("the C gather could not start its threads")
    return g_pos, g_metric, g_flux
