"""Build of the compiled extension (operators.kernels._simd); everything else is in pyproject.toml.

It holds the AVX2 splat / gather / jet kernels and the height-field photon kernels in C, compiled
here once, so that a run does not wait for numba to compile them. ``optional=True``: where no C
compiler is found the package still installs, and the numba kernels do the extension's work
(same results to rounding).
"""

from setuptools import Extension, setup

setup(ext_modules=[Extension("operators.kernels._simd",
                             sources=["operators/kernels/simd_kernels.c", "operators/kernels/heightfield_photons.c",
                                      "operators/kernels/coverage_kernels.c"],
                             depends=["operators/kernels/sfc_threads.h"],
                             extra_compile_args=["-O3", "-pthread"], extra_link_args=["-pthread"], optional=True)])
