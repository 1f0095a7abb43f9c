"""Iterative solvers and their step-size policies and preconditioners.

The plugins (entry points in pyproject.toml): solvers ``gradient_descent`` (M1),
``landweber_pixel`` (M2) and ``landweber_wavelet`` (M3), all configurations of one
proximal-gradient iteration; step sizes ``constant`` and ``backtracking``; the preconditioner
``sobolev``. A solver plugin's ``from_config(**solver keys)`` checks its config and returns a
builder ``(problem, d0) -> solver`` (framework/core/problem.py).
"""

from framework.core.solver_loop import (Callback, IterationFailed, IterationRecord, IterativeSolver, RunResult,
                                        SolverState)
from framework.optimization.preconditioner import GradientPreconditioner, SobolevPreconditioner
from framework.optimization.step_size import (BacktrackingStep, ConstantStep, LineSearchFailed, StepChoice,
                                              StepSizePolicy, as_step_policy)
from framework.reconstruction.solvers.pixel_methods import GradientDescent, PixelLandweber
from framework.reconstruction.solvers.proximal_gradient import ProximalGradientSolver
from framework.reconstruction.solvers.wavelet_landweber import WaveletLandweber

__all__ = [
    "Callback",
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
