"""The contract of a setup calibration (kind ``calibration``): parts of the setup (gain, screen
distance, light, screen blur) fitted together with the heights, as a callback of the height solver.

The ``calibration`` config group names the plugin (``calibration.name``; the built-in ``joint``,
framework/lab/calibration.py) and its settings. A reconstruction
(framework/reconstruction/reconstruction.py) builds it before anything is rendered
(``from_config``: None where nothing is calibrated), hands it the data once they are loaded
(:meth:`SetupCalibration.setup`), runs it beside every solve, reads whether a start must be solved
again under the calibrated setup (:meth:`SetupCalibration.needs_refit`) and writes its report
into metrics.json and the verdict.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from torch import Tensor

from framework.core.solver_loop import Callback
from operators.plugin import Plugin
from operators.scene import Scene

__all__ = ["SetupCalibration"]


class SetupCalibration(Callback, Plugin, ABC):
    """Fits setup parameters beside the height solver (module docstring)."""

    @classmethod
    @abstractmethod
    def from_config(cls, operator: Any, settings: Mapping[str, Any], scene: Scene | None = None,
                    screen_sigma: float = 0.0, volume_held: bool = False) -> SetupCalibration | None:
        """The calibration of the config group ``calibration`` (without ``name``) for the run's
        ``operator`` and configured ``scene``, or None where nothing is calibrated;
        ``screen_sigma``: the configured screen blur (scene units); ``volume_held``: a post-step
        keeps the known volume."""

    @abstractmethod
    def setup(self, target: Tensor, weights: Tensor | None, delta: float, state_path: Path,
              resume_from: Path | None = None, goal: float | None = None) -> None:
        """The data b (c, n, n), their weights and noise level delta; its state goes to
        ``state_path``, ``resume_from`` restores an interrupted run's; ``goal``: the discrepancy the
        stopping rule accepts."""

    @abstractmethod
    def gain_of_shot(self, index: int) -> SetupCalibration | None:
        """The calibration of shot ``index``'s gain alone (a stack's first fit on its nearest shot),
        or None."""

    @abstractmethod
    def values(self) -> dict[str, float]:
        """The current value of every calibrated parameter."""

    @abstractmethod
    def needs_refit(self, before: Mapping[str, float]) -> bool:
        """Whether the heights fitted since ``before`` (:meth:`values` when the run began) absorbed
        a move of the setup, so that a run from the start under the calibrated setup is needed."""

    @abstractmethod
    def describe_move(self, before: Mapping[str, float]) -> str:
        """How the setup moved from ``before``, in words."""

    @abstractmethod
    def never_updated(self) -> list[str]:
        """The calibrated parameters no update has moved (they keep their configured values)."""

    @abstractmethod
    def report(self) -> dict[str, float]:
        """Every parameter's start, final value and standard error, for metrics.json."""
