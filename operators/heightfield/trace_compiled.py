"""Host side of the height-field photon kernels in C (``operators/kernels/heightfield_photons.c``).

The same render and gradient as the numba kernels (:mod:`operators.heightfield.kernels_native`,
:mod:`operators.heightfield.adjoint_native`), photon for photon, but compiled at install as part
of the extension (:mod:`operators.kernels.extension`): the first run after an install traces at
once instead of waiting for numba to compile. ctypes releases the GIL for the call; the C code
runs its own threads, one per image (or gradient) buffer it is given.
"""

from __future__ import annotations

import ctypes

import numba as nb
import numpy as np

from operators.emission import R2_STEP
from operators.heightfield.intersect_native import MAX_MARCH_STEPS, NEWTON_ITERATIONS, SETTLE
from operators.heightfield.kernels_native import FusedScene
from operators.heightfield.side_walls import BESIDE, FOLD_LIMIT
from operators.kernels import extension
from operators.optics.reference import GRAZING
from operators.splat.native import FAR_PX
from operators.splat.splat import MAX_DIFFERENTIAL_PX

_INTS = {"per_channel", "fresnel", "simd", "clear_walls", "max_march_steps", "newton_iterations"}
# The C struct sfc_scene: FusedScene's fields, then the constants the numba kernels import.
_FIELDS = (*FusedScene._fields, "r2_u", "r2_v", "grazing", "max_differential_px", "settle", "max_march_steps",
           "newton_iterations", "far_px", "fold_limit", "beside")
_CONSTANTS = dict(r2_u=R2_STEP[0], r2_v=R2_STEP[1], grazing=GRAZING, max_differential_px=MAX_DIFFERENTIAL_PX,
                  settle=SETTLE, max_march_steps=MAX_MARCH_STEPS, newton_iterations=NEWTON_ITERATIONS, far_px=FAR_PX,
                  fold_limit=FOLD_LIMIT, beside=BESIDE)


class SceneStruct(ctypes.Structure):
    """``sfc_scene`` of heightfield_photons.c."""

    _fields_ = [(name, ctypes.c_int64 if name in _INTS else ctypes.c_double) for name in _FIELDS]


_P = ctypes.c_void_p
_I = ctypes.c_int64


def _bind() -> extension.Kernels:
    """The extension with the height-field kernels' signatures declared, as the build that
    traces (:func:`operators.kernels.extension.bind`)."""
    scene = ctypes.POINTER(SceneStruct)
    return extension.bind((
        ("sfc_hf_render", [_P, _I, scene, _P, _P, _I, _I, _P, _I, _I, _I, _I, _I, _I, _P, _I, _I,
                           ctypes.POINTER(ctypes.c_double)], ctypes.c_int),
        ("sfc_hf_vjp", [_P, _I, scene, _P, _P, _I, _I, _P, _I, _I, _P, _I, _P, _I], ctypes.c_int),
        ("sfc_hf_trace_aimed", [_P, _I, scene, ctypes.c_double, _P, _I, _P, _P, _P, _I], ctypes.c_int)))


_KERNELS = _bind()
AVAILABLE = _KERNELS.available  # whether the C photon kernels were built (they run on any CPU)


def _pointer(array: np.ndarray | None) -> int | None:
    return None if array is None or array.size == 0 else array.ctypes.data


def scene_struct(values: dict[str, float]) -> SceneStruct:
    """``sfc_scene`` from FusedScene's fields in ``values`` (those missing: 0) and the constants."""
    values = {**values, **_CONSTANTS}
    return SceneStruct(**{name: int(values.get(name, 0)) if name in _INTS else float(values.get(name, 0.0))
                          for name in _FIELDS})


def _scene(sc: FusedScene) -> SceneStruct:
    return scene_struct(sc._asdict())


def _check(d: np.ndarray, out: np.ndarray, dims: int, **arrays: np.ndarray) -> None:
    """The C kernels address raw memory: heights (m, m) float64, buffers with a leading thread axis
    of at least one, float64 C-contiguous inputs; anything else is refused here."""
    if d.ndim != 2 or d.shape[0] != d.shape[1] or d.shape[0] < 2 or d.dtype != np.float64:
        raise ValueError(f"heights must be a square float64 array of side >= 2, got {d.dtype} {d.shape}")
    if out.ndim != dims or out.shape[0] < 1:
        raise ValueError(f"the output buffers must have shape (threads >= 1, ...) with {dims} axes, got {out.shape}")
    for name, array in {"d": d, "out": out, **arrays}.items():
        if not array.flags.c_contiguous or (name != "out" and array.size and array.dtype != np.float64):
            raise ValueError(f"{name} must be a C-contiguous float64 array")


def render(d: np.ndarray, sc: FusedScene, shifts: np.ndarray, indices: np.ndarray, start: int, stop: int,
           out: np.ndarray, capacity: int, splat: bool, hit_t: np.ndarray, replay: bool) -> float:
    """:func:`operators.heightfield.kernels_native.render_photons` in C: photons start .. stop-1 into
    ``out`` (threads, c, n, n) float32 or float64, one thread per image; returns the flux that
    reached the receiver. Arrays C-contiguous, ``d``, ``shifts``, ``indices`` and ``hit_t`` float64
    (``hit_t`` empty: no hits recorded)."""
    if out.dtype not in (np.float32, np.float64):
        raise ValueError(f"images must be float32 or float64, not {out.dtype}")
    _check(d, out, 4, shifts=shifts, indices=indices, hit_t=hit_t)
    if out.shape[1] != shifts.shape[0] or out.shape[2] != out.shape[3] or hit_t.size not in (0, stop - start):
        raise ValueError(
            f"images {out.shape} must be square, one channel per emission shift ({shifts.shape[0]}); hit_t "
            f"{hit_t.shape} must be empty or hold stop - start = {stop - start} photons"
        )
    reached = ctypes.c_double(0.0)
    status = _KERNELS.function("sfc_hf_render")(
        d.ctypes.data, d.shape[0], ctypes.byref(_scene(sc)), shifts.ctypes.data, indices.ctypes.data, start, stop,
        out.ctypes.data, int(out.dtype == np.float32), out.shape[0], out.shape[1], out.shape[2], capacity, int(splat),
        _pointer(hit_t), hit_t.shape[0], int(replay), ctypes.byref(reached))
    if status != 0:
        raise MemoryError("the C photon kernels could not allocate their buffers or start their threads")
    return reached.value


def vjp(d: np.ndarray, sc: FusedScene, shifts: np.ndarray, indices: np.ndarray, start: int, stop: int,
        padded: np.ndarray, pad: int, out: np.ndarray, hit_t: np.ndarray) -> None:
    """:func:`operators.heightfield.adjoint_native.vjp_photons` in C: adds the gradient into ``out``
    (threads, m, m) float64, one thread per gradient; ``padded`` (c, n + 2 pad, n + 2 pad)
    float64; ``hit_t`` replayed unless empty."""
    _check(d, out, 3, shifts=shifts, indices=indices, padded=padded, hit_t=hit_t)
    if (
        out.dtype != np.float64
        or out.shape[1:] != d.shape
        or padded.shape[0] != shifts.shape[0]
        or hit_t.size not in (0, stop - start)
    ):
        raise ValueError(
            f"gradients {out.dtype} {out.shape} must be float64 (threads, *{d.shape}), the padded image {padded.shape} "
            f"one channel per emission shift ({shifts.shape[0]}), hit_t empty or stop - start long"
        )
    status = _KERNELS.function("sfc_hf_vjp")(
        d.ctypes.data, d.shape[0], ctypes.byref(_scene(sc)), shifts.ctypes.data, indices.ctypes.data, start, stop,
        padded.ctypes.data, padded.shape[1] - 2 * pad, pad, out.ctypes.data, out.shape[0], _pointer(hit_t),
        hit_t.shape[0])
    if status != 0:
        raise MemoryError("the C photon kernels could not allocate their buffers or start their threads")


def trace_aimed(d: np.ndarray, sc: FusedScene, eta: float, aim: np.ndarray, pos: np.ndarray,
                ratio: np.ndarray, path: np.ndarray) -> None:
    """:func:`operators.wavefront.renderer._trace_native` in C: rays aimed at ``aim`` (N, 2) (x, y
    on the substrate's top plane) through heights ``d`` (m, m), glass index ``eta``: receiver
    positions (N, 2) (pixel corner units) into ``pos``, transmittances (N,) into ``ratio``, path
    codes (N,) (operators/heightfield/side_walls.py) into ``path``; all float64, C-contiguous; as
    many threads as numba's."""
    for name, array, shape in (("aim", aim, (aim.shape[0], 2)), ("pos", pos, (aim.shape[0], 2)),
                               ("ratio", ratio, (aim.shape[0],)), ("path", path, (aim.shape[0],))):
        if array.shape != shape or array.dtype != np.float64 or not array.flags.c_contiguous:
            raise ValueError(f"{name} must be a C-contiguous float64 array of shape {shape}")
    trace_aimed = _KERNELS.function("sfc_hf_trace_aimed")
    if trace_aimed(d.ctypes.data, d.shape[0], ctypes.byref(_scene(sc)), float(eta), aim.ctypes.data, aim.shape[0],
                   pos.ctypes.data, ratio.ctypes.data, path.ctypes.data, nb.get_num_threads()) != 0:
        raise MemoryError("the C photon kernels could not start their threads")
