"""The AVX2 kernels of ``operators/kernels/simd_kernels.c`` for numba: the splat and gather of the fixed
8 x 8 pixel box and of larger footprints (over each row's chord of the ellipse), the surface jets at
the hits of a packet, and the adjoint of a surface hit into the 4 x 4 heights around it.

numba calls the C functions by symbol name (``ExternalFunction``), so kernels that call them can
still be cached on disk: the symbols are resolved again in every process. Where the extension
was not built or is stale (:mod:`operators.kernels.extension`) or the CPU lacks AVX2 / FMA, the
symbols are bound to a function that does nothing, so the kernels still link, and ``AVAILABLE``
is False: the kernels then take their numba branch (they test ``FusedScene.simd`` / their
``simd`` argument, which the host sets from ``AVAILABLE`` and ``operator.simd``).

numba does not see the C functions in its cache keys: after changing their signatures, bump the
ABI version (``extension.ABI_VERSION`` and ``sfc_abi_version``) and delete the kernels' caches
(``operators/__pycache__/*.nb*``).
"""

from __future__ import annotations

import ctypes

import llvmlite.binding as llvm
from numba import config, types
from numba.extending import intrinsic

from operators.kernels import extension


def _load() -> bool:
    """Load the extension's symbols into numba's JIT; whether its kernels can run here (not with
    the JIT off: plain Python cannot call them)."""
    if config.DISABLE_JIT:
        return False
    library = extension.load()
    if library is None:
        return False
    try:
        supported = bool(library.sfc_simd_supported())
        if supported:
            llvm.load_library_permanently(extension.origin())
    except (OSError, AttributeError, RuntimeError):
        return False
    return supported


AVAILABLE = _load()

_F64P = types.CPointer(types.float64)
# (image, first pixel's element offset, row stride (elements), rows, rx0, ry0, q00, q01, q11, flux)
_SPLAT_ARGS = (types.int64, types.int64, types.int64, *[types.float64] * 6)
splat_box8_f64 = types.ExternalFunction("sfc_splat_box8_f64", types.void(_F64P, *_SPLAT_ARGS))
splat_box8_f32 = types.ExternalFunction("sfc_splat_box8_f32", types.void(types.CPointer(types.float32), *_SPLAT_ARGS))
# (G, first pixel's element offset, row stride, rows, rx0, ry0, q00, q01, q11, sums (12,))
gather_box8 = types.ExternalFunction(
    "sfc_gather_box8", types.void(_F64P, types.int64, types.int64, types.int64, *[types.float64] * 5, _F64P))
# (image, first pixel's element offset, row stride, rows, columns, rx0, ry0, q00, q01, q11, flux)
_SPANS_ARGS = (types.int64, types.int64, types.int64, types.int64, *[types.float64] * 6)
splat_spans_f64 = types.ExternalFunction("sfc_splat_spans_f64", types.void(_F64P, *_SPANS_ARGS))
splat_spans_f32 = types.ExternalFunction("sfc_splat_spans_f32", types.void(types.CPointer(types.float32), *_SPANS_ARGS))
# (G, first pixel's element offset, row stride, rows, columns, rx0, ry0, q00, q01, q11, sums (12,))
gather_spans = types.ExternalFunction(
    "sfc_gather_spans", types.void(_F64P, *[types.int64] * 4, *[types.float64] * 5, _F64P))
# (d, grad, m, x, y, origin, 1 / spacing, w_x, w_y, w_z, g_t, g_sx, g_sy, g_sxx, g_sxy, g_syy)
hit_adjoint = types.ExternalFunction("sfc_hit_adjoint", types.void(_F64P, _F64P, types.int64, *[types.float64] * 13))
# (d, m, origin, 1 / spacing, ox, oy, dirs, row stride, t, count, jets)
surface_jets = types.ExternalFunction(
    "sfc_surface_jets", types.void(_F64P, types.int64, *[types.float64] * 4, _F64P, types.int64, _F64P,
                                   types.int64, _F64P))

if not AVAILABLE:
    _NEVER_CALLED = ctypes.CFUNCTYPE(None)(lambda: None)
    for _kernel in (splat_box8_f64, splat_box8_f32, gather_box8, splat_spans_f64, splat_spans_f32,
                    gather_spans, hit_adjoint, surface_jets):
        if not llvm.address_of_symbol(_kernel.symbol):
            llvm.add_symbol(_kernel.symbol, ctypes.cast(_NEVER_CALLED, ctypes.c_void_p).value)


@intrinsic
def data_pointer(typingctx, array):
    """Pointer to the first element of a numba array (its data, whatever its layout)."""
    signature = types.CPointer(array.dtype)(array)

    def codegen(context, builder, sig, args):
        return context.make_array(sig.args[0])(context, builder, args[0]).data

    return signature, codegen
