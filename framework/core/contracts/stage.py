"""The contract of a run stage (kind ``stage``): a feature that joins every reconstruction
without the run knowing it.

A reconstruction (framework/reconstruction/reconstruction.py) builds every installed stage from
the run's config before anything is rendered: ``from_config(cfg)`` reads and checks the stage's
own config group and returns None where the stage has nothing to do in such a run. Each stage, in
turn by its ``order``, then meets the run at three points:

- :meth:`RunStage.phases` may add starts to try after the configured ones (a stack's search of
  its nearest shot's lines, framework/stack/stack_stage.py);
- before each solve from a start, :meth:`RunStage.begin` may solve part of the problem first and
  hand over other heights to start from (a stack's nearest shot);
- after the solve, :meth:`RunStage.revise` may replace the returned heights (the check of
  undecided beads, framework/tracks/ambiguity_stage.py);
- once the run has rendered its prediction and written its outputs and its own verdict,
  :meth:`RunStage.report` adds metrics and verdict sentences (a stack's shots; the fitted tracks,
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

from framework.core.contracts.calibration import SetupCalibration
from framework.core.contracts.representation import Representation
from framework.core.contracts.start import Start, StartRequest
from framework.core.problem import Problem
from framework.core.solver_loop import Callback, RunResult
from operators.image_operator import ImageOperator
from operators.scene import Scene
from operators.plugin import Plugin

__all__ = ["Refit", "RunStage", "Solve", "SolvedRun", "StageReport", "StartingRun"]

# heights d0 (m, m), a label for the progress bar -> (the returned heights (m, m), their relative
# discrepancy, whether a stopping rule ended the fit rather than the solver's iteration cap)
Refit = Callable[[Tensor, str], tuple[Tensor, float, bool]]
# a problem (the run's, or one shot's), heights d0 (m, m), a label for the progress bar, callbacks
# besides the run's stopping rules and photon budget -> (the returned heights (m, m), the run)
Solve = Callable[[Problem, Tensor, str, list[Callback]], tuple[Tensor, RunResult]]


@dataclass
class StartingRun:
    """What a stage sees of a run about to solve from a start.

    Attributes:
        problem: The run's problem.
        start: The start the heights came from (a plugin of kind ``initial``, or a phase a stage
            added).
        heights: The start d0 (m, m), scene units.
        shaped: Whether the start holds the print's shape (not flat glass).
        solve: The run's own solver, fresh stopping rules and photon budget on a problem
            (:data:`Solve`).
        calibration: The run's calibration of the setup, or None.
        output_dir: The run's directory.
        seed: The run's seed.
    """

    problem: Problem
    start: Start
    heights: Tensor
    shaped: bool
    solve: Solve
    calibration: SetupCalibration | None
    output_dir: Path
    seed: int


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
        operator_for: The run's configured operator for another scene (another screen distance,
            say), not seen through a camera.
        mm_per_unit: Millimetres per scene unit.
        seed: The run's seed.
        tau_dis: Morozov's factor: a fit reaches the noise level at tau_dis * delta.
        output_dir: The run's directory.
        prediction: The rendered prediction (c, n, n) of the reported heights, set before
            :meth:`RunStage.report` (None before).
    """

    problem: Problem
    heights: Tensor
    fitted: Any
    refit: Refit
    operator_for: Callable[[Scene], ImageOperator]
    mm_per_unit: float
    seed: int
    tau_dis: float
    output_dir: Path
    prediction: Tensor | None = None

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
        order: Stages run by ascending order (a stack's shots 5, the ambiguity check 10, the tracks
            20, the defects 30).
    """

    order: ClassVar[int] = 100

    def phases(self, problem: Problem, runnable: list[tuple[str, Start]], request: StartRequest
               ) -> list[tuple[str, Start]]:
        """Starts (name, start) to try after the configured ones, given those that these data can
        run (``runnable``) and the request the run's starts read; here none."""
        return []

    def begin(self, run: StartingRun) -> tuple[Tensor, dict[str, float]] | None:
        """Other heights (m, m) to start the solve from and what finding them cost (metrics, named
        without the start's prefix), or None (here: none)."""
        return None

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
