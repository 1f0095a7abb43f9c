"""The contract of a stopping rule (kind ``stopping``, config group ``stopping``): a solver-loop
callback (:class:`framework.core.solver_loop.Callback`) that asks the loop to stop.

Every run from a start gets fresh rules, built from the config; before the run,
``setup(problem)`` hands each rule the problem (the noise level delta, the volume). A rule whose
stop means the current iterate is the solution sets ``stop_accepts_iterate = True``; a rule that
gives up may offer ``best_iterate()`` to report instead.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

from framework.core.problem import Problem
from framework.core.solver_loop import Callback, IterationRecord, IterativeSolver
from operators.plugin import Plugin

__all__ = ["StoppingRule"]


class StoppingRule(Callback, Plugin, ABC):
    """Base of the stopping rules: a callback with ``setup`` whose ``on_iteration`` is its test."""

    @abstractmethod
    def on_iteration(self, solver: IterativeSolver, record: IterationRecord) -> bool | None:
        """True to stop after this iteration (``stop_reason`` set first)."""

    def setup(self, problem: Problem) -> None:
        """Take what the rule needs of the problem before the run (nothing by default)."""
