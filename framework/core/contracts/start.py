"""The contract of a start plugin (kind ``initial``, config group ``initial``): the heights d0 the
solver starts from.

A start is built from its config group by ``from_config(**params)`` (or its constructor), which
checks every value before anything is rendered; ``check(base_dir)`` checks what it reads (before
the run opens); once the data are loaded, ``start(request) -> StartResult``. A start that tries
several candidates (``initial=auto``) lists them in ``phases()``: the reconstruction runs the
solver from each in turn. :class:`Start` gives the defaults (nothing to check, one phase).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path

from torch import Tensor

from framework.core.problem import Problem
from operators.plugin import Plugin

__all__ = ["Start", "StartRequest", "StartResult"]


@dataclass(frozen=True)
class StartRequest:
    """What a start may use: the problem (never the ground truth of synthetic data,
    framework/core/truth.py) and the design the data carry.

    Attributes:
        problem: The operator, data (target, mask, volume, noise level, design), grid and scene.
        base_dir: Directory relative paths are resolved against.
        deadline: A ``time.perf_counter()`` value by which a start that can stop early (a
            transport's Newton) ends and says so; None: none.
    """

    problem: Problem
    base_dir: Path
    deadline: float | None = None

    def design(self) -> Tensor:
        """A copy of the print's design (m, m), scene units, as the data carry it; a ValueError
        for data without one (synthetic data of the configured height field carry none: those
        heights are the answer)."""
        design = self.problem.data.design
        if design is None:
            raise ValueError("these data carry no design of the print: a start that reads it needs a measured "
                             "print's height_field.path=<design> or synthetic data of another print "
                             "(data.printed=<print>); choose initial=transport, zero or file")
        return design.clone()


@dataclass
class StartResult:
    """A start d0 (m, m), scene units, in the operator's dtype, and what computing it measured
    (logged with the run as ``start_*`` metrics). ``shaped``: d0 already holds the print's broad
    shape (a transport, a design, a file), so the solver begins at its finest stage
    (:meth:`framework.core.solver_loop.IterativeSolver.begin_from_shaped_start`)."""

    d: Tensor
    metrics: dict[str, float] = field(default_factory=dict)
    name: str = ""
    shaped: bool = False


class Start(Plugin, ABC):
    """Base of the start plugins.

    Attributes:
        name: The start's name in metrics and logs (``start_<name>_*``).
        reads_design: True for a start that reads the print's design (``initial=auto`` skips it
            where the data carry none; a start that wraps another declares what that one reads).
    """

    name: str = "start"
    reads_design: bool = False

    def check(self, base_dir: Path) -> None:
        """Check what the start reads (files), before the run opens; a bad one raises naming the key."""

    def phases(self) -> list[tuple[str, Start]]:
        """(name, start) of every candidate the solver runs from, in order: this start alone."""
        return [(self.name, self)]

    @abstractmethod
    def __call__(self, request: StartRequest) -> StartResult:
        """The start d0 for the loaded data."""
