"""The linear pieces of the image chain (operators/linear/linear_map.py): composed with ``@``, each
with its adjoint and a dot test."""

from operators.linear.block_mean import BlockMean
from operators.linear.gaussian_blur import GaussianBlur
from operators.linear.linear_map import Composition, Gain, LinearMap, all_linear_maps, dot_test
from operators.linear.shot_weights import ShotWeights

__all__ = ["BlockMean", "Composition", "Gain", "GaussianBlur", "LinearMap", "ShotWeights",
           "all_linear_maps", "dot_test"]
