"""Host side of the mesh-scene event kernels in C (``operators/kernels/mesh_events.c``).

:func:`advance`, :func:`retreat`, :func:`splat_arguments` and :func:`splat_arguments_adjoint`
take the arguments of the numba kernels of the same names (:mod:`operators.mesh.kernels_native`,
:mod:`operators.mesh.adjoint_native`) and compute the same, photon for photon, but compiled at
install as part of the extension (:mod:`operators.kernels.extension`): the first render through
lenses traces at once instead of waiting for numba. ctypes releases the GIL for the call; the C
code runs as many threads as numba would.
"""

from __future__ import annotations

import ctypes

import numba as nb
import numpy as np

from operators.heightfield.trace_compiled import SceneStruct, scene_struct
from operators.kernels import extension
from operators.mesh import kernels_native as mk
from operators.mesh.culling import CLEAR_COS
from operators.mesh.embree_native import INTERSECT1
from operators.mesh.intersect_reference import MIN_FACE_DISTANCE, START_OFFSET

__all__ = ["AVAILABLE", "advance", "retreat", "splat_arguments", "splat_arguments_adjoint"]

_P = ctypes.c_void_p
_I = ctypes.c_int64


class _MeshScene(ctypes.Structure):
    """``mesh_scene`` of mesh_events.c."""

    _fields_ = [("hf", SceneStruct), ("top_max", ctypes.c_double), ("lowest", ctypes.c_double),
                ("start_offset", ctypes.c_double), ("min_face_distance", ctypes.c_double),
                ("clear_cos", ctypes.c_double)]


class _Faces(ctypes.Structure):
    """``mesh_faces`` of mesh_events.c."""

    _fields_ = [("face_element", _P), ("face_clear", _P), ("v0", _P), ("plane", _P), ("dual", _P), ("shading", _P),
                ("neighbour", _P), ("indices", _P), ("channels", _I), ("substrate", _I), ("embree", _P),
                ("intersect1", _P)]


class _Photons(ctypes.Structure):
    """``event_photons`` of mesh_events.c."""

    _fields_ = [("d", _P), ("m", _I), ("state", _P), ("medium", _P), ("channel", _P), ("status", _P), ("clear", _P),
                ("kind", _P), ("which", _P), ("t", _P), ("lost_fresnel", _P), ("before", _P), ("n", _I),
                ("released", _I), ("replay", _I), ("wait_at_top", _I)]


def _bind() -> ctypes.CDLL | None:
    library = extension.load()
    if library is None:
        return None
    scene, faces, photons = (ctypes.POINTER(s) for s in (_MeshScene, _Faces, _Photons))
    for name, argtypes, restype in (
            ("sfc_mesh_advance", [scene, faces, photons, _I], ctypes.c_int),
            ("sfc_mesh_retreat", [scene, faces, photons, _P, _P, _I], ctypes.c_int),
            ("sfc_mesh_splat_arguments", [scene, _P, _P, _P, _I, _P, _P, _P], None),
            ("sfc_mesh_splat_arguments_adjoint", [scene, _P, _P, _I, _P, _P, _P, _P], None)):
        function = getattr(library, name)
        function.argtypes = argtypes
        function.restype = restype
    return library


_LIBRARY = _bind()
AVAILABLE = _LIBRARY is not None  # whether the C event kernels were built


def _scene(sc: mk.MeshConstants) -> _MeshScene:
    hf = scene_struct(dict(half=sc.half, base=sc.thickness, spacing=sc.spacing, zlo=sc.zlo, zstart=sc.zstart,
                           zhi=sc.zhi, slope_x=sc.slope_x, slope_y=sc.slope_y, receiver_z=sc.receiver_z,
                           receiver_half=sc.receiver_half, to_px=sc.to_px, min_px=sc.min_px, max_px=sc.max_px,
                           fresnel=sc.fresnel))
    return _MeshScene(hf, sc.top_max, sc.lowest, START_OFFSET, MIN_FACE_DISTANCE, CLEAR_COS)


def _data(array: np.ndarray, dtype: type, name: str) -> int:
    """The address of a C-contiguous array of ``dtype``; anything else is refused (the C code
    addresses raw memory)."""
    if array.dtype != dtype or not array.flags.c_contiguous:
        raise ValueError(f"{name} must be a C-contiguous {np.dtype(dtype).name} array, got {array.dtype} "
                         f"{'contiguous' if array.flags.c_contiguous else 'strided'}")
    return array.ctypes.data


def _faces(substrate: int, face_element: np.ndarray, face_clear: np.ndarray, indices: np.ndarray, v0: np.ndarray,
           plane: np.ndarray, dual: np.ndarray, shading: np.ndarray, neighbour: np.ndarray, handle: int) -> _Faces:
    return _Faces(_data(face_element, np.int64, "face_element"), _data(face_clear, np.bool_, "face_clear"),
                  _data(v0, np.float64, "v0"), _data(plane, np.float64, "plane"), _data(dual, np.float64, "dual"),
                  _data(shading, np.float64, "shading"), _data(neighbour, np.int64, "neighbour"),
                  _data(indices, np.float64, "indices"), indices.shape[1], substrate, handle or None,
                  INTERSECT1 if handle else None)


def _photons(d: np.ndarray, state: np.ndarray, medium: np.ndarray, channel: np.ndarray, status: np.ndarray,
             clear: np.ndarray, kind: np.ndarray, which: np.ndarray, t: np.ndarray, lost_fresnel: np.ndarray | None,
             before: np.ndarray | None, released: bool, replay: bool, wait_at_top: bool) -> _Photons:
    n = state.shape[0]
    if state.shape != (n, mk.STATE) or any(a.shape != (n,) for a in (medium, channel, status, clear, kind, which, t)):
        raise ValueError(f"photon arrays must be state (N, {mk.STATE}) and (N,) each, with N = {n}")
    if d.ndim != 2 or d.shape[0] != d.shape[1]:
        raise ValueError(f"heights must be a square array, got {d.shape}")
    return _Photons(_data(d, np.float64, "d"), d.shape[0], _data(state, np.float64, "state"),
                    _data(medium, np.int64, "medium"), _data(channel, np.int64, "channel"),
                    _data(status, np.int64, "status"), _data(clear, np.bool_, "clear"), _data(kind, np.int64, "kind"),
                    _data(which, np.int64, "which"), _data(t, np.float64, "t"),
                    None if lost_fresnel is None else _data(lost_fresnel, np.float64, "lost_fresnel"),
                    None if before is None or before.shape[0] == 0 else _data(before, np.float64, "before"),
                    n, int(released), int(replay), int(wait_at_top))


def _check_status(status: int) -> None:
    if status != 0:
        raise MemoryError("the C mesh kernels could not start their threads")


def advance(d, state, medium, channel, status, clear, released, handle, kind_out, which_out, t_out, replay,
            lost_fresnel, before, wait_at_top, substrate, face_element, face_clear, indices, v0, plane, dual, shading,
            neighbour, sc) -> None:
    """:func:`operators.mesh.kernels_native.advance` in C (same arguments)."""
    if before.shape[0] not in (0, state.shape[0]) or lost_fresnel.shape != (state.shape[0],):
        raise ValueError("before must have no rows or one per photon, lost_fresnel one value per photon")
    photons = _photons(d, state, medium, channel, status, clear, kind_out, which_out, t_out, lost_fresnel, before,
                       released, replay, wait_at_top)
    faces = _faces(substrate, face_element, face_clear, indices, v0, plane, dual, shading, neighbour, handle)
    _check_status(_LIBRARY.sfc_mesh_advance(ctypes.byref(_scene(sc)), ctypes.byref(faces), ctypes.byref(photons),
                                            nb.get_num_threads()))


def retreat(d, before, kind, which, t, channel, substrate, face_element, indices, v0, plane, dual, shading, sc,
            g_after, g_heights) -> None:
    """:func:`operators.mesh.adjoint_native.retreat` in C (same arguments); one thread per row of
    ``g_heights`` (threads, m, m)."""
    n = before.shape[0]
    if g_after.shape != (n, mk.STATE) or g_heights.ndim != 3 or g_heights.shape[1:] != d.shape:
        raise ValueError(f"g_after must be (N, {mk.STATE}) like before, g_heights (threads, *{d.shape})")
    unused = np.zeros(n, dtype=np.int64)
    photons = _photons(d, before, unused, channel, unused, np.zeros(n, dtype=np.bool_), kind, which, t, None, before,
                       False, True, False)
    no_clear = np.zeros(1, dtype=np.bool_)
    faces = _faces(substrate, face_element, no_clear, indices, v0, plane, dual, shading, np.zeros((1, 3), np.int64), 0)
    _check_status(_LIBRARY.sfc_mesh_retreat(ctypes.byref(_scene(sc)), ctypes.byref(faces), ctypes.byref(photons),
                                            _data(g_after, np.float64, "g_after"),
                                            _data(g_heights, np.float64, "g_heights"), g_heights.shape[0]))


def splat_arguments(state, status, where, sc, pos, metric, flux) -> None:
    """:func:`operators.mesh.kernels_native.splat_arguments` in C (same arguments)."""
    n = state.shape[0]
    if where.shape != (n,) or pos.shape != (2, n) or metric.shape != (3, n) or flux.shape != (n,):
        raise ValueError(f"where (N,), pos (2, N), metric (3, N), flux (N,) for N = {n} photons")
    _LIBRARY.sfc_mesh_splat_arguments(ctypes.byref(_scene(sc)), _data(state, np.float64, "state"),
                                      _data(status, np.int64, "status"), _data(where, np.int64, "where"), n,
                                      _data(pos, np.float64, "pos"), _data(metric, np.float64, "metric"),
                                      _data(flux, np.float64, "flux"))


def splat_arguments_adjoint(state, status, sc, g_pos, g_metric, g_flux, g_state) -> None:
    """:func:`operators.mesh.adjoint_native.splat_arguments_adjoint` in C (same arguments)."""
    n = state.shape[0]
    if g_pos.shape != (2, n) or g_metric.shape != (3, n) or g_flux.shape != (n,) or g_state.shape != state.shape:
        raise ValueError(f"g_pos (2, N), g_metric (3, N), g_flux (N,), g_state like state for N = {n} photons")
    _LIBRARY.sfc_mesh_splat_arguments_adjoint(ctypes.byref(_scene(sc)), _data(state, np.float64, "state"),
                                              _data(status, np.int64, "status"), n,
                                              _data(g_pos, np.float64, "g_pos"), _data(g_metric, np.float64, "g_metric"),
                                              _data(g_flux, np.float64, "g_flux"),
                                              _data(g_state, np.float64, "g_state"))
