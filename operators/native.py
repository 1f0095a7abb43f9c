"""Shared settings of the numba kernels."""

# LLVM fast-math flags without 'nnan'/'ninf', so that NaN and infinity checks stay meaningful.
FAST_MATH = {"nsz", "arcp", "contract", "afn", "reassoc"}
