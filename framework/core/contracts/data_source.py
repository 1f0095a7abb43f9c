"""The contract of a data plugin (kind ``data``, config group ``data``): where the caustic image,
the printed area, the volume and the noise level of a reconstruction come from.

A data plugin is built from its config keys alone (every value checked, nothing read or rendered);
``check(request)`` then reads and checks its files and what it knows of the print without
rendering (before a run opens), and ``load(request)`` produces the
:class:`framework.core.data.ReconstructionData`. A source of several shots of the print, each in
its own setup (:class:`ShotStack`), also gives their setups: the run then renders through the
stacked operator of those setups (operators/stack.py), and the request's operator is that one.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from collections.abc import Callable, Sequence

import torch

from framework.core.data import ReconstructionData
from framework.core.problem import HeightGrid
from framework.core.shots import ShotSetup
from framework.core.units import DEFAULT_MM_PER_UNIT
from operators.image_operator import ImageOperator
from operators.plugin import Plugin
from operators.scene import Scene

__all__ = ["DataRequest", "DataSource", "PrintFacts", "ShotStack"]


@dataclass(frozen=True)
class DataRequest:
    """What a data source may use.

    Attributes:
        operator: The reconstruction's forward operator (its ``variant`` renders references).
        grid: The height grid of the reconstruction.
        configured_heights: Returns the configured height field (m, m), float64, scene units: the
            print that synthetic data render (their ground truth, which leaves the source sealed:
            framework/core/truth.py), the design of a measured print (``data.mask=design``).
        seed: The run's seed (reference renders and noise derive their seeds from it).
        base_dir: Directory against which relative file names are resolved.
        output_dir: The run directory, for what a source shows of its work (figures, logs).
        mm_per_unit: Millimetres per scene unit (framework/core/units.py), for volumes given in mm3.
    """

    operator: ImageOperator
    grid: HeightGrid
    configured_heights: Callable[[], torch.Tensor]
    seed: int
    base_dir: Path
    output_dir: Path | None = None
    mm_per_unit: float = DEFAULT_MM_PER_UNIT


@dataclass(frozen=True)
class PrintFacts:
    """What a data source's check knows of the print before anything is rendered.

    Attributes:
        mask: The printed area (m, m) bool.
        volume: The deposited volume, scene units^3, or None when unknown (or not known yet).
        volume_at_load: True when the data know the volume once they load (synthetic data: the
            ground truth's), though not before.
    """

    mask: torch.Tensor
    volume: float | None
    volume_at_load: bool = False


class DataSource(Plugin, ABC):
    """Base of the ``data`` plugins: built from its config keys, it produces the data on request."""

    @abstractmethod
    def check(self, request: DataRequest) -> PrintFacts:
        """Read and check every file and value the data need, rendering nothing; a bad one raises
        a ValueError / FileNotFoundError naming the key and the fix."""

    @abstractmethod
    def load(self, request: DataRequest) -> ReconstructionData:
        """The target image, mask, volume and noise level (and, for synthetic data, the truth as a
        :class:`framework.core.truth.GroundTruth`)."""


class ShotStack(DataSource):
    """Base of a ``data`` plugin of several shots of one print (framework/stack/stack_data.py)."""

    @abstractmethod
    def setups(self, base: Scene, mm: float) -> Sequence[ShotSetup]:
        """Every shot's setup against the configured scene ``base`` (``mm`` millimetres per scene
        unit); an impossible one (a screen inside the glass) raises a ValueError naming the shot."""
