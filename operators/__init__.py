"""Forward operators: photons from a point light through printed glass onto a receiver."""

from operators.caustic_operator import CausticOperator, OperatorSettings
from operators.materials import FUSED_SILICA, Cauchy, ConstantIndex, Sellmeier
from operators.scene import PointLight, Receiver, Scene, Substrate

__all__ = ["CausticOperator", "OperatorSettings", "Scene", "PointLight", "Substrate", "Receiver",
           "Sellmeier", "Cauchy", "ConstantIndex", "FUSED_SILICA"]
