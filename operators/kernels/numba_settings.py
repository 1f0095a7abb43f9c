"""Shared settings and helpers of the numba kernels."""

import numba as nb
import numpy as np
import torch

# LLVM fast-math flags without 'nnan'/'ninf', so that NaN and infinity checks stay meaningful.
FAST_MATH = {"nsz", "arcp", "contract", "afn", "reassoc"}

# The three ways the CPU kernels are compiled (cached on disk, float semantics as above): a helper
# inlined into its caller, a function called by a kernel, and a kernel whose loop runs on threads.
jit_inline = nb.njit(cache=True, inline="always", fastmath=FAST_MATH, error_model="numpy")
jit_call = nb.njit(cache=True, fastmath=FAST_MATH, error_model="numpy")
jit_parallel = nb.njit(parallel=True, cache=True, fastmath=FAST_MATH, error_model="numpy")


def to_numpy(t: torch.Tensor) -> np.ndarray:
    """A contiguous host array view (or copy) of a tensor, for handing to a kernel."""
    return t.detach().cpu().contiguous().numpy()
