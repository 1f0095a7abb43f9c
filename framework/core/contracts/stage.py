"""The contract of a run stage (kind ``stage``): a feature that joins every reconstruction after
its solve, without the run knowing it.

A reconstruction (framework/reconstruction/reconstruction.py) builds every installed stage from
the run's config before anything is rendered: ``from_config(cfg)`` reads and checks the stage's
own config group and returns None where the stage has nothing to do in such a run. After the solver
has returned its heights, each stage in turn (by its ``order``) may replace them
(:meth:`RunStage.revise`: the check of undecided beads, framework/tracks/ambiguity_stage.py); the
run then renders its prediction, writes its outputs and its own verdict, and each stage adds its
metrics and verdict sentences (:meth:`RunStage.report`: the fitted tracks,
framework/tracks/track_stage.py; the defects against the design,
framework/defects/defect_stage.py). A stage prints its own sentences as ``verdict:`` lines.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from torch import Tensor

from framework.core.contracts.representation import Representation
from framework.core.problem import Problem
from operators.plugin import Plugin

__all__ = ["Refit", "RunStage", "SolvedRun", "StageReport"]

# heights d0 (m, m), a label for the progress bar -> (the returned heights (m, m), their relative
# discrepancy, whether a stopping rule ended the fit rather than the solver's iteration cap)
Refit = Callable[[Tensor, str], tuple[Tensor, float, bool]]


@dataclass
class SolvedRun:
    """What a stage sees of a reconstruction once its solver returned.

    Attributes:
        problem: The run's problem (operator, data without the truth, grid, scene).
        heights: The returned heights d (m, m), scene units.
        fitted: What the solver fitted besides the heights (RunResult.fitted: a representation
            and its parameters), or None.
        refit: The run's own solver, stopping rules and photon budget, run again from other
            heights (:data:`Refit`).
        cfg: The run's plain config.
        mm_per_unit: Millimetres per scene unit.
        seed: The run's seed.
        tau_dis: Morozov's factor: a fit reaches the noise level at tau_dis * delta.
        output_dir: The run's directory.
    """

    problem: Problem
    heights: Tensor
    fitted: Any
    refit: Refit
    cfg: Mapping[str, Any]
    mm_per_unit: float
    seed: int
    tau_dis: float
    output_dir: Path

    @property
    def representation(self) -> Representation | None:
        """The representation the solver fitted, or None (a free grid)."""
        return self.fitted[0] if self.fitted is not None else None

    @property
    def beads_fitted(self) -> bool:
        """Whether the solver fitted beads along tracks (a representation that declares
        ``describes_beads``): their count and their defects are the tracks' stage's to report."""
        representation = self.representation
        return representation is not None and representation.describes_beads


@dataclass(frozen=True)
class StageReport:
    """A stage's additions to the run's metrics.json and to its verdict (sentences, in order)."""

    metrics: dict[str, Any] = field(default_factory=dict)
    lines: list[str] = field(default_factory=list)


class RunStage(Plugin, ABC):
    """A feature that joins a reconstruction after its solve (module docstring).

    Attributes:
        order: Stages run by ascending order (the ambiguity check 10, the tracks 20, the defects 30).
    """

    order: ClassVar[int] = 100

    @classmethod
    @abstractmethod
    def from_config(cls, cfg: Mapping[str, Any]) -> RunStage | None:
        """The stage for a run of ``cfg`` (its own group checked; a bad value is a ValueError in one
        line), or None where it has nothing to do in such a run."""

    def revise(self, run: SolvedRun) -> Tensor | None:
        """Other heights (m, m) to report instead of ``run.heights``, or None (here: none)."""
        return None

    def report(self, run: SolvedRun) -> StageReport:
        """The stage's metrics and verdict sentences, its files written into ``run.output_dir``
        (here: nothing)."""
        return StageReport()
