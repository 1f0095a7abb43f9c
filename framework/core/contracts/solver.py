"""The contract of a solver plugin (kind ``solver``, config group ``solver``).

The registered object is a subclass of :class:`framework.core.solver_loop.IterativeSolver` whose
class method ``from_config(**settings)`` checks the ``solver`` group (``max_iter`` aside, which the
loop takes) and returns a :data:`SolverBuilder`; once the data and the start are known,
``builder(problem, d0)`` makes the solver, whose ``step()`` does one iteration and whose
``run(max_iter, callbacks)`` the pipeline drives.
"""

from __future__ import annotations

from collections.abc import Callable

from torch import Tensor

from framework.core.problem import Problem
from framework.core.solver_loop import IterativeSolver

__all__ = ["SolverBuilder"]

# What a solver plugin's ``from_config`` returns: makes the solver once the problem and the start
# d0 (m, m) are known.
SolverBuilder = Callable[[Problem, Tensor], IterativeSolver]
