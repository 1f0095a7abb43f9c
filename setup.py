"""Build of the optional AVX2 extension (operators.kernels._simd); everything else is in pyproject.toml.

``optional=True``: where no C compiler is found the package still installs, and the numba kernels
do the extension's work (same results to rounding).
"""

from setuptools import Extension, setup

setup(ext_modules=[Extension("operators.kernels._simd", sources=["operators/kernels/simd_kernels.c"],
                             extra_compile_args=["-O3"], optional=True)])
