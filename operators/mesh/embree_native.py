"""Embree's single-ray query inside numba kernels, so that the mesh-scene kernels find faces on
every thread without returning to Python.

embreex ships the Embree 4 library; it is loaded into numba's JIT and its ``rtcIntersect1`` is
called by symbol name (as :mod:`operators.kernels.simd` calls its C kernels, so the kernels stay cached on
disk). :class:`EmbreeTriangles` builds a scene of triangles through the library's C API (ctypes)
and hands the kernels its handle; :func:`first_face` traces one ray in it.
"""

from __future__ import annotations

import ctypes
import glob
import math
import os
from typing import Any

import embreex
import llvmlite.binding as llvm
import numpy as np
from numba import types
from numba.extending import intrinsic

from operators.kernels.numba_settings import jit_inline
from operators.kernels.simd import data_pointer

__all__ = ["EmbreeTriangles", "INTERSECT8", "first_face", "ray_buffer", "RAY_FLOATS"]

# Embree 4 enums (rtcore_common.h, rtcore_buffer.h, rtcore_geometry.h).
_GEOMETRY_TRIANGLE = 0
_BUFFER_INDEX, _BUFFER_VERTEX = 0, 1
_FORMAT_UINT3, _FORMAT_FLOAT3 = 0x5003, 0x9003
_INVALID_ID = 0xFFFFFFFF
# RTCRayHit as float32 slots: origin 0-2, tnear 3, direction 4-6, time 7, tfar 8, mask 9, id 10,
# flags 11; hit: Ng 12-14, u 15, v 16, primID 17, geomID 18, instance ids after. 16-byte aligned.
RAY_FLOATS = 32
_PRIM_ID, _GEOM_ID = 17, 18


def _library_path() -> str:
    libs = os.path.join(os.path.dirname(os.path.dirname(embreex.__file__)), "embreex.libs")
    found = sorted(glob.glob(os.path.join(libs, "libembree4*.so*")))
    if not found:
        raise ImportError(f"no Embree 4 library in {libs}; reinstall embreex")
    return found[0]


_PATH = _library_path()
_LIB = ctypes.CDLL(_PATH)
llvm.load_library_permanently(_PATH)
for _name, _res, _args in (("rtcNewDevice", ctypes.c_void_p, [ctypes.c_char_p]),
                           ("rtcNewScene", ctypes.c_void_p, [ctypes.c_void_p]),
                           ("rtcNewGeometry", ctypes.c_void_p, [ctypes.c_void_p, ctypes.c_int]),
                           ("rtcSetNewGeometryBuffer", ctypes.c_void_p,
                            [ctypes.c_void_p, ctypes.c_int, ctypes.c_uint, ctypes.c_int, ctypes.c_size_t,
                             ctypes.c_size_t]),
                           ("rtcCommitGeometry", None, [ctypes.c_void_p]),
                           ("rtcAttachGeometry", ctypes.c_uint, [ctypes.c_void_p, ctypes.c_void_p]),
                           ("rtcReleaseGeometry", None, [ctypes.c_void_p]),
                           ("rtcCommitScene", None, [ctypes.c_void_p]),
                           ("rtcReleaseScene", None, [ctypes.c_void_p]),
                           ("rtcReleaseDevice", None, [ctypes.c_void_p]),
                           ("rtcGetDeviceError", ctypes.c_int, [ctypes.c_void_p])):
    getattr(_LIB, _name).restype = _res
    getattr(_LIB, _name).argtypes = _args

# The address of rtcIntersect8(valid int[8], scene handle, RTCRayHit8*, RTCIntersectArguments* = NULL),
# for the C kernels (operators/kernels/mesh_events.c), which trace eight rays at a time; numba calls
# rtcIntersect1 by name.
INTERSECT8 = ctypes.cast(_LIB.rtcIntersect8, ctypes.c_void_p).value
_intersect1 = types.ExternalFunction("rtcIntersect1", types.void(types.int64, types.CPointer(types.float32),
                                                                 types.int64))


class EmbreeTriangles:
    """An Embree scene of triangles (vertices (V, 3), faces (F, 3)); ``handle`` for the kernels.
    Face ids are the rows of ``faces``."""

    _scene: Any = None  # set once the scene exists; released by __del__

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self._device = _LIB.rtcNewDevice(None)
        self._scene = _LIB.rtcNewScene(self._device)
        geometry = _LIB.rtcNewGeometry(self._device, _GEOMETRY_TRIANGLE)
        v = np.ascontiguousarray(vertices, dtype=np.float32)
        f = np.ascontiguousarray(faces, dtype=np.uint32)
        ctypes.memmove(_LIB.rtcSetNewGeometryBuffer(geometry, _BUFFER_VERTEX, 0, _FORMAT_FLOAT3, 12, len(v)),
                       v.ctypes.data, v.nbytes)
        ctypes.memmove(_LIB.rtcSetNewGeometryBuffer(geometry, _BUFFER_INDEX, 0, _FORMAT_UINT3, 12, len(f)),
                       f.ctypes.data, f.nbytes)
        _LIB.rtcCommitGeometry(geometry)
        _LIB.rtcAttachGeometry(self._scene, geometry)
        _LIB.rtcReleaseGeometry(geometry)
        _LIB.rtcCommitScene(self._scene)
        error = _LIB.rtcGetDeviceError(self._device)
        if error:
            raise RuntimeError(f"Embree could not build the scene of {len(f)} faces (error code {error})")
        self.handle = int(self._scene)

    def __del__(self) -> None:
        if self._scene:
            _LIB.rtcReleaseScene(self._scene)
            _LIB.rtcReleaseDevice(self._device)
            self._scene = None


@intrinsic
def _address(typingctx, array):
    """The address of an array's first element, as an integer."""
    def codegen(context, builder, signature, args):
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        return builder.ptrtoint(data, context.get_value_type(types.int64))
    return types.int64(array), codegen


_jit = jit_inline


@_jit
def ray_buffer():
    """A 16-byte aligned float32 buffer of RAY_FLOATS for :func:`first_face` (one per thread)."""
    raw = np.empty(RAY_FLOATS + 4, dtype=np.float32)
    skip = ((16 - _address(raw) % 16) % 16) // 4
    return raw[skip:skip + RAY_FLOATS]


@_jit
def first_face(handle, ray, ox, oy, oz, wx, wy, wz) -> int:
    """The first face that the ray from (ox, oy, oz) (float32) along (wx, wy, wz) meets, -1 for none."""
    bits = ray.view(np.uint32)
    ray[0], ray[1], ray[2], ray[3] = ox, oy, oz, 0.0
    ray[4], ray[5], ray[6], ray[7] = wx, wy, wz, 0.0
    ray[8] = math.inf
    bits[9], bits[10], bits[11] = _INVALID_ID, 0, 0
    bits[_GEOM_ID] = _INVALID_ID
    bits[_PRIM_ID] = _INVALID_ID
    _intersect1(handle, data_pointer(ray), 0)
    return -1 if bits[_GEOM_ID] == _INVALID_ID else int(bits[_PRIM_ID])
