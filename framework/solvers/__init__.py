"""Iterative solvers (registered as ``solver/<name>``) and their step-size policies.

Importing this package registers every solver: ``gradient_descent`` (M1), ``landweber_pixel``
(M2) and ``landweber_wavelet`` (M3), all configurations of one proximal-gradient iteration.
"""

from .base import IterationFailed, IterationRecord, IterativeSolver, RunResult, SolverState
from .preconditioner import GradientPreconditioner, SobolevPreconditioner
from .proximal_gradient import GradientDescent, PixelLandweber, ProximalGradientSolver
from .step_size import BacktrackingStep, ConstantStep, LineSearchFailed, StepChoice, StepSizePolicy, as_step_policy
from .wavelet_landweber import WaveletLandweber

__all__ = [
    "IterativeSolver",
    "IterationRecord",
    "RunResult",
    "SolverState",
    "IterationFailed",
    "ProximalGradientSolver",
    "GradientDescent",
    "PixelLandweber",
    "WaveletLandweber",
    "GradientPreconditioner",
    "SobolevPreconditioner",
    "StepSizePolicy",
    "ConstantStep",
    "BacktrackingStep",
    "StepChoice",
    "LineSearchFailed",
    "as_step_policy",
]
