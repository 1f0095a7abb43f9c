"""Host side of the mesh-scene photon kernels in C (``operators/kernels/mesh_events.c``).

:func:`trace` takes a chunk of photons through all their events in one call (what
:func:`operators.mesh.kernels_native.advance` does one event per call) and gives their splat
arguments (what :func:`operators.mesh.kernels_native.splat_arguments` computes from the final
states), and :func:`reverse` takes the gradient w.r.t. the landed photons' splat arguments back
to the heights (what :func:`operators.mesh.adjoint_native.splat_arguments_adjoint` and
:func:`operators.mesh.adjoint_native.retreat`, one event per call from a tape, do).
Compiled at install as part of the extension (:mod:`operators.kernels.extension`): the first
render through lenses traces at once instead of waiting for numba. ctypes releases the GIL for
the call; the C code runs as many threads as numba would.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass

import numba as nb
import numpy as np

from operators.heightfield.trace_compiled import SceneStruct, scene_struct
from operators.kernels import extension
from operators.kernels.simd import AVAILABLE as SIMD_AVAILABLE
from operators.mesh import kernels_native as mk
from operators.mesh.culling import CLEAR_COS
from operators.mesh.embree_native import INTERSECT8
from operators.mesh.intersect_reference import MIN_FACE_DISTANCE, START_OFFSET

__all__ = ["AVAILABLE", "BYTES_PER_EVENT", "LOSS_KINDS", "EventLog", "Faces", "SplatArguments", "trace", "reverse"]

_P = ctypes.c_void_p
_I = ctypes.c_int64
# The flux lost, per kind (rows of the trace's losses; LOSSES in trace_native.py).
LOSS_KINDS = ("escaped", "inside_top", "fresnel_reflected", "max_depth", "missed_receiver")
# Memory of one logged event: int8 kind, int32 face or plane, float64 distance.
BYTES_PER_EVENT = 13


class _MeshScene(ctypes.Structure):
    """``mesh_scene`` of mesh_events.c."""

    _fields_ = [("hf", SceneStruct), ("top_max", ctypes.c_double), ("lowest", ctypes.c_double),
                ("start_offset", ctypes.c_double), ("min_face_distance", ctypes.c_double),
                ("clear_cos", ctypes.c_double)]


class _Faces(ctypes.Structure):
    """``mesh_faces`` of mesh_events.c."""

    _fields_ = [("face_element", _P), ("face_clear", _P), ("v0", _P), ("plane", _P), ("dual", _P), ("shading", _P),
                ("neighbour", _P), ("indices", _P), ("channels", _I), ("substrate", _I), ("embree", _P),
                ("intersect8", _P)]


class _Chunk(ctypes.Structure):
    """``chunk_job`` of mesh_events.c."""

    _fields_ = [("d", _P), ("m", _I), ("state", _P), ("start", _P), ("medium", _P), ("channel", _P), ("status", _P),
                ("events", _P), ("clear", _P), ("lost", _P), ("log_kind", _P), ("log_which", _P), ("log_t", _P),
                ("pos", _P), ("metric", _P), ("flux", _P), ("g_pos", _P), ("g_metric", _P), ("g_flux", _P),
                ("g_heights", _P), ("n", _I), ("max_depth", _I), ("wait_at_top", _I), ("replay", _I), ("threads", _I)]


def _bind() -> extension.Kernels:
    """The extension with the mesh kernels' signatures declared, as the build that traces
    (:func:`operators.kernels.extension.bind`)."""
    scene, faces, chunk = (ctypes.POINTER(s) for s in (_MeshScene, _Faces, _Chunk))
    return extension.bind((
        ("sfc_mesh_trace", [scene, faces, chunk], ctypes.c_int),
        ("sfc_mesh_reverse", [scene, faces, chunk], ctypes.c_int),
        ("sfc_mesh_block", [], ctypes.c_int64)))


_KERNELS = _bind()
AVAILABLE = _KERNELS.available  # whether the C photon kernels of mesh scenes were built


def _scene(sc: mk.MeshConstants) -> _MeshScene:
    hf = scene_struct(dict(half=sc.half, base=sc.thickness, spacing=sc.spacing, zlo=sc.zlo, zstart=sc.zstart,
                           zhi=sc.zhi, slope_x=sc.slope_x, slope_y=sc.slope_y, receiver_z=sc.receiver_z,
                           receiver_half=sc.receiver_half, to_px=sc.to_px, min_px=sc.min_px, max_px=sc.max_px,
                           fresnel=sc.fresnel, simd=SIMD_AVAILABLE))
    return _MeshScene(hf, sc.top_max, sc.lowest, START_OFFSET, MIN_FACE_DISTANCE, CLEAR_COS)


def _data(array: np.ndarray, dtype: type, name: str, shape: tuple[int, ...]) -> int:
    """The address of a C-contiguous array of ``dtype`` and ``shape``; anything else is refused
    (the C code addresses raw memory)."""
    if array.dtype != dtype or not array.flags.c_contiguous or array.shape != shape:
        raise ValueError(f"{name} must be a C-contiguous {np.dtype(dtype).name} array of shape {shape}, got "
                         f"{array.dtype} {array.shape}{'' if array.flags.c_contiguous else ' (strided)'}")
    return array.ctypes.data


class Faces:
    """The elements' faces as the kernels read them (NativeMeshTracer's arrays: face_element (F,),
    face_clear (F,) bool, v0 and plane (F, 3), dual (F, 2, 3), shading (F, 3, 3), neighbour (F, 3),
    the refractive indices (K + 1, c), the substrate's row K) and the Embree scene (handle, 0 for
    none). Keeps the arrays alive while the kernels hold their addresses."""

    def __init__(self, substrate: int, face_element: np.ndarray, face_clear: np.ndarray, indices: np.ndarray,
                 v0: np.ndarray, plane: np.ndarray, dual: np.ndarray, shading: np.ndarray, neighbour: np.ndarray,
                 handle: int) -> None:
        f = len(face_element)
        self._arrays = (face_element, face_clear, indices, v0, plane, dual, shading, neighbour)
        self.struct = _Faces(
            _data(face_element, np.int64, "face_element", (f,)),
            _data(face_clear, np.bool_, "face_clear", (max(f, 1),)),
            _data(v0, np.float64, "v0", (f, 3)), _data(plane, np.float64, "plane", (f, 3)),
            _data(dual, np.float64, "dual", (f, 2, 3)), _data(shading, np.float64, "shading", (f, 3, 3)),
            _data(neighbour, np.int64, "neighbour", (f, 3)), _data(indices, np.float64, "indices", indices.shape),
            indices.shape[1], substrate, handle or None, INTERSECT8 if handle else None)


@dataclass
class EventLog:
    """The photons' events in one trace (max_depth, N), event by event so that the kernels read
    and write consecutive photons' event together: kind (-1 past a photon's last), face or box
    plane, distance."""

    kind: np.ndarray
    which: np.ndarray
    t: np.ndarray

    @classmethod
    def empty(cls, n: int, max_depth: int) -> EventLog:
        return cls(np.empty((max_depth, n), np.int8), np.empty((max_depth, n), np.int32), np.empty((max_depth, n)))


@dataclass
class SplatArguments:
    """What the splat takes of N photons (:func:`operators.mesh.kernels_native.splat_arguments`):
    pixel position (2, N), footprint metric (3, N) and flux (N,) (0 for a photon that did not
    land)."""

    pos: np.ndarray
    metric: np.ndarray
    flux: np.ndarray

    @classmethod
    def empty(cls, n: int) -> SplatArguments:
        return cls(np.empty((2, n)), np.empty((3, n)), np.empty(n))


def _chunk(d: np.ndarray, state: np.ndarray | None, medium: np.ndarray, channel: np.ndarray, status: np.ndarray,
           events: np.ndarray, clear: np.ndarray, max_depth: int, wait_at_top: bool, log: EventLog | None,
           replay: bool = False, lost: np.ndarray | None = None, splat: SplatArguments | None = None,
           g_splat: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
           g_heights: np.ndarray | None = None, start: np.ndarray | None = None) -> _Chunk:
    n = (state if state is not None else start).shape[0]
    if d.ndim != 2 or d.shape[0] != d.shape[1]:
        raise ValueError(f"heights must be a square array, got {d.shape}")
    logged = (None, None, None) if log is None else (
        _data(log.kind, np.int8, "log.kind", (max_depth, n)), _data(log.which, np.int32, "log.which", (max_depth, n)),
        _data(log.t, np.float64, "log.t", (max_depth, n)))
    threads = nb.get_num_threads() if g_heights is None else g_heights.shape[0]
    return _Chunk(
        _data(d, np.float64, "d", d.shape), d.shape[0],
        None if state is None else _data(state, np.float64, "state", (n, mk.STATE)),
        None if start is None else _data(start, np.float64, "start", (n, mk.STATE)),
        _data(medium, np.int64, "medium", (n,)), _data(channel, np.int64, "channel", (n,)),
        _data(status, np.int64, "status", (n,)), _data(events, np.int64, "events", (n,)),
        _data(clear, np.bool_, "clear", (n,)),
        None if lost is None else _data(lost, np.float64, "lost", (len(LOSS_KINDS), _blocks(n))),
        *logged,
        *((None, None, None) if splat is None else (
            _data(splat.pos, np.float64, "pos", (2, n)), _data(splat.metric, np.float64, "metric", (3, n)),
            _data(splat.flux, np.float64, "flux", (n,)))),
        *((None, None, None) if g_splat is None else (
            _data(g_splat[0], np.float64, "g_pos", (2, n)), _data(g_splat[1], np.float64, "g_metric", (3, n)),
            _data(g_splat[2], np.float64, "g_flux", (n,)))),
        None if g_heights is None else _data(g_heights, np.float64, "g_heights", (threads, *d.shape)),
        n, max_depth, int(wait_at_top), int(replay), threads)


def _blocks(n: int) -> int:
    """Blocks of the C kernels' threads in a chunk of ``n`` photons (the trace's losses hold a
    column per block)."""
    return -(-n // _KERNELS.function("sfc_mesh_block")())


def _check_status(status: int) -> None:
    if status != 0:
        raise MemoryError("the C mesh kernels could not allocate their buffers or start their threads")


def trace(d: np.ndarray, state: np.ndarray | None, medium: np.ndarray, channel: np.ndarray, status: np.ndarray,
          events: np.ndarray, clear: np.ndarray, max_depth: int, wait_at_top: bool, faces: Faces,
          sc: mk.MeshConstants, splat: SplatArguments, log: EventLog | None = None, replay: bool = False,
          start: np.ndarray | None = None) -> dict[str, float]:
    """Every photon under way through its events (at most ``max_depth``, until it lands, is lost,
    or with ``wait_at_top`` waits above the print; lost too once ``events`` (N,), counted over its
    whole path, reaches ``max_depth``), in place: ``state`` (N, STATE), ``medium``, ``status``,
    ``events``, ``clear`` (N,); heights ``d`` (m, m). With ``start`` (N, STATE) the photons start
    from there and ``state`` only receives them (None: their final states are not kept; ``start``
    is not written). Every photon's splat
    arguments into ``splat``, photon i's at column i. Records the events into
    ``log``, or with ``replay`` takes them from it (logged at the same heights: no search).
    Returns the flux lost per kind (W; :data:`LOSS_KINDS`, summed block by block in photon order)."""
    if replay and log is None:
        raise ValueError("a replay needs the log of the events")
    if state is None and start is None:
        raise ValueError("a trace without final states needs its photons' start")
    lost = np.empty((len(LOSS_KINDS), _blocks(len(status))))
    job = _chunk(d, state, medium, channel, status, events, clear, max_depth, wait_at_top, log, replay, lost,
                 splat, start=start)
    trace_chunk = _KERNELS.function("sfc_mesh_trace")
    _check_status(trace_chunk(ctypes.byref(_scene(sc)), ctypes.byref(faces.struct), ctypes.byref(job)))
    return {kind: float(total) for kind, total in zip(LOSS_KINDS, lost.sum(axis=1))}


def reverse(d: np.ndarray, start: tuple[np.ndarray, np.ndarray, np.ndarray], channel: np.ndarray,
            status: np.ndarray, log: EventLog, faces: Faces, sc: mk.MeshConstants,
            g_splat: tuple[np.ndarray, np.ndarray, np.ndarray], g_heights: np.ndarray) -> None:
    """Add to ``g_heights`` (threads, m, m), one thread per row, the gradient w.r.t. the heights
    ``d`` of the gradient ``g_splat`` w.r.t. the landed photons' splat arguments (pos (2, N),
    metric (3, N), flux (N,), photon i's at column i, as :func:`trace` gives them): ``start``
    (state, medium, clear) as the photons were before the :func:`trace` that filled ``log``,
    ``status`` (N,) as they were after it."""
    state, medium, clear = start
    job = _chunk(d, state, medium, channel, status, np.zeros(len(state), np.int64), clear, log.kind.shape[0], False,
                 log, True, g_splat=g_splat, g_heights=g_heights)
    reverse_chunk = _KERNELS.function("sfc_mesh_reverse")
    _check_status(reverse_chunk(ctypes.byref(_scene(sc)), ctypes.byref(faces.struct), ctypes.byref(job)))
