"""The contract of a solver plugin (kind ``solver``, config group ``solver``).

The registered object's ``from_config(**settings)`` checks the ``solver`` group (``max_iter``
aside, which the loop takes) and returns a :data:`SolverBuilder`; once the data and the start are
known, ``builder(problem, d0)`` makes the :class:`framework.core.solver_loop.IterativeSolver`,
whose ``step()`` does one iteration and whose ``run(max_iter, callbacks)`` the pipeline drives.
"""

from __future__ import annotations

from typing import Any, Callable, Protocol, runtime_checkable

from torch import Tensor

from framework.core.problem import Problem
from framework.core.solver_loop import IterativeSolver

__all__ = ["SolverBuilder", "SolverPlugin"]

# What a solver plugin's ``from_config`` returns: makes the solver once the problem and the start
# d0 (m, m) are known.
SolverBuilder = Callable[[Problem, Tensor], IterativeSolver]


@runtime_checkable
class SolverPlugin(Protocol):
    """The registered solver: its settings checked into a builder."""

    def from_config(self, **settings: Any) -> SolverBuilder:
        """The builder of this solver for the ``solver`` group's settings; a bad value is a ValueError."""
        ...
