"""Shared settings and helpers of the numba kernels."""

import numpy as np
import torch

# LLVM fast-math flags without 'nnan'/'ninf', so that NaN and infinity checks stay meaningful.
FAST_MATH = {"nsz", "arcp", "contract", "afn", "reassoc"}


def to_numpy(t: torch.Tensor) -> np.ndarray:
    """A contiguous host array view (or copy) of a tensor, for handing to a kernel."""
    return t.detach().cpu().contiguous().numpy()
