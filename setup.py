"""Build of the compiled extension (operators.kernels._simd); everything else is in pyproject.toml.

It holds the AVX2 splat / gather / jet kernels, the height-field photon kernels and the
mesh-scene event kernels in C, compiled here once, so that a run does not wait for numba to
compile them. ``optional=True``: where no C compiler is found the package still installs, and the
numba kernels do the extension's work (same results to rounding).
"""

from setuptools import Extension, setup

# The float semantics of the numba kernels (operators/kernels/numba_settings.py, FAST_MATH):
# contraction into FMA, reassociation, reciprocals, no signed zeros, no errno from the maths; not
# finite-math-only, so that NaN and infinity checks keep their meaning.
FAST_MATH = ["-fno-math-errno", "-fno-trapping-math", "-fno-signed-zeros", "-freciprocal-math", "-fassociative-math",
             "-ffp-contract=fast"]

setup(ext_modules=[Extension("operators.kernels._simd",
                             sources=["operators/kernels/simd_kernels.c", "operators/kernels/heightfield_photons.c",
                                      "operators/kernels/heightfield_photons_avx2.c",
                                      "operators/kernels/coverage_kernels.c", "operators/kernels/mesh_events.c",
                                      "operators/kernels/mesh_events_avx2.c"],
                             depends=["operators/kernels/sfc_threads.h", "operators/kernels/photon_optics.h",
                                      "operators/kernels/heightfield_photons.c", "operators/kernels/mesh_events.c"],
                             extra_compile_args=["-O3", "-pthread", *FAST_MATH], extra_link_args=["-pthread"],
                             optional=True)])
