"""Regularizers of the height-field reconstruction: values, proximal maps and post-step updates.

The plugins (declared as entry points in pyproject.toml; kind ``regularizer`` unless noted):

- ``l1_pixel``   :class:`PixelL1`            alpha ||d||_1
- ``bounds``     :class:`HeightBounds`       indicator of [p1, p2] on the mask N^, 0 off it
- ``l1_bounds``  :class:`PixelL1Bounds`      both at once; its prox is the paper's eq. (7)
- ``l1_wavelet`` :class:`WaveletL1`          alpha_w ||W d||_1, orthogonal Daubechies DWT
- ``l1_design``  :class:`PixelL1DesignBounds` alpha ||d - c||_1 + bounds, c the print's design
- ``volume_v1``  :class:`VolumeHeuristic`    the paper's volume heuristic eq. (8) (kind ``post_step``)
- ``volume_v2``  :class:`VolumeSlabL1Bounds` eq. (7) plus an exact volume slab constraint (a prox)
- ``volume_hold`` :class:`VolumeHold`       the projection onto bounds, mask and a narrow volume band
  (kind ``post_step``)
"""

from .base import CoefficientRegularizer, CoefficientTransform, PostStepUpdate, Regularizer, RegularizerContext
from .bounds import HeightBounds
from .l1_bounds import PixelL1Bounds
from .l1_design import PixelL1DesignBounds
from .pixel_l1 import PixelL1
from .shrinkage import clamp_on_mask, soft_shrink
from .volume_heuristic import VolumeHeuristic, volume_band, window_mean
from .volume_hold import VolumeHold
from .volume_prox import VolumeSlabL1Bounds
from .wavelet import WaveletL1, WaveletTransform

__all__ = [
    "CoefficientRegularizer",
    "CoefficientTransform",
    "HeightBounds",
    "PixelL1",
    "PixelL1Bounds",
    "PixelL1DesignBounds",
    "PostStepUpdate",
    "Regularizer",
    "RegularizerContext",
    "VolumeHeuristic",
    "VolumeHold",
    "VolumeSlabL1Bounds",
    "WaveletL1",
    "WaveletTransform",
    "clamp_on_mask",
    "soft_shrink",
    "volume_band",
    "window_mean",
]
