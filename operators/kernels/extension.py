"""The compiled extension ``operators.kernels._simd`` (setup.py), loaded once with ctypes.

It holds the AVX2 splat, gather, jet and hit-adjoint kernels (``simd_kernels.c``, called from
numba: :mod:`operators.kernels.simd`) and the whole height-field photon kernels in C
(``heightfield_photons.c``, called from the host: :mod:`operators.heightfield.trace_compiled`; its
splat and gather also for photons that other tracers computed: :mod:`operators.splat.compiled`) and
the mesh-scene event kernels (``mesh_events.c``: :mod:`operators.mesh.events_compiled`), all
compiled at install; the photon kernels twice, for any x86-64 CPU and for AVX2 + FMA, so neither waits for a
JIT. Where it was not built (no C compiler at
install) or was built from other sources (its ``sfc_abi_version`` differs from
:data:`ABI_VERSION`), :func:`load` returns None and the numba kernels do its work.
"""

from __future__ import annotations

import ctypes
import functools
import importlib.util
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

# Version of the C functions' signatures that the declarations in Python match (sfc_abi_version).
ABI_VERSION = 13
# Suffixes of the two builds of the photon kernels (heightfield_photons.c, mesh_events.c): baseline, AVX2 + FMA.
BUILDS = ("", "_avx2")


@functools.cache
def load() -> ctypes.CDLL | None:
    """The extension's library, or None where it is missing or stale (with a warning naming the fix)."""
    spec = importlib.util.find_spec("operators.kernels._simd")
    if spec is None or spec.origin is None:
        return None
    try:
        library = ctypes.CDLL(spec.origin)
        version = library.sfc_abi_version()
    except (OSError, AttributeError):
        return None
    if version != ABI_VERSION:
        warnings.warn(f"{spec.origin} was built from other sources (ABI {version}, need {ABI_VERSION}); using the "
                      "numba kernels. Rebuild it: pip install -e .", stacklevel=2)
        return None
    return library


@dataclass
class Kernels:
    """The extension's functions of one build: ``suffix`` is that build's (BUILDS); ``library``
    None where the extension is missing or stale."""

    library: ctypes.CDLL | None
    suffix: str

    @property
    def available(self) -> bool:
        """Whether the extension was built (and matches these sources)."""
        return self.library is not None

    def function(self, name: str):
        """The extension's function ``name`` of this build."""
        assert self.library is not None, "the compiled extension is not built"
        return getattr(self.library, name + self.suffix)


def bind(signatures: Sequence[tuple[str, list, type | None]]) -> Kernels:
    """The extension with each (name, argtypes, restype) declared for both builds (BUILDS), as
    the build to call: ``_avx2`` where the CPU has AVX2 and FMA, else the baseline (the AVX2 build
    is empty off x86-64)."""
    library = load()
    if library is None:
        return Kernels(None, "")
    for suffix in BUILDS:
        for name, argtypes, restype in signatures:
            function = getattr(library, name + suffix, None)
            if function is not None:
                function.argtypes = argtypes
                function.restype = restype
    return Kernels(library, "_avx2" if library.sfc_simd_supported() else "")


def origin() -> str:
    """The extension's file (for loading its symbols into another runtime)."""
    spec = importlib.util.find_spec("operators.kernels._simd")
    assert spec is not None and spec.origin is not None
    return spec.origin
