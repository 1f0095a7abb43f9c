"""The contract of a stopping rule (kind ``stopping``, config group ``stopping``): a solver-loop
callback (:class:`framework.core.solver_loop.Callback`) that asks the loop to stop.

Every run from a start gets fresh rules, built from the config; before the run,
``setup(problem)`` hands each rule the problem (the noise level delta, the volume). A rule whose
stop means the current iterate is the solution sets ``stop_accepts_iterate = True``; a rule that
gives up may offer ``best_iterate()`` to report instead.
"""

from __future__ import annotations

from framework.core.problem import Problem
from framework.core.solver_loop import Callback

__all__ = ["StoppingRule"]


class StoppingRule(Callback):
    """Base of the stopping rules: a callback with ``setup``."""

    def setup(self, problem: Problem) -> None:
        """Take what the rule needs of the problem before the run (nothing by default)."""
