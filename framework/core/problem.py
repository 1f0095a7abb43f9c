"""The reconstruction problem every solver receives: the operator, the data, the height grid and
the scene.

A solver plugin's builder gets a :class:`Problem` and the start d0; it takes what its method
needs from it: the data term (:attr:`Problem.fidelity`), the regularisers' context (mask, volume,
cell area), the target image, the grid, the scene's geometry and material (a caustic-design
method traces its own rays), the operator itself.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

from operators.image_operator import ImageOperator
from framework.core.data import ReconstructionData
from framework.core.objective import DataFidelity
from operators.scene import Scene
from operators.values import checked_whole
from regularizers import RegularizerContext

__all__ = ["HeightGrid", "Problem"]


@dataclass(frozen=True)
class HeightGrid:
    """The grid of the printed heights d (m, m): samples at linspace(-W, W, m) in x and y.

    Attributes:
        resolution: m, samples per side.
        half_width: W, scene units (the substrate's half width).
        base: Height of the glass under the print (the substrate thickness h, scene units): the
            relative error is taken of h + d (framework/core/callbacks.py, GroundTruthError).
    """

    resolution: int
    half_width: float
    base: float

    def __post_init__(self) -> None:
        checked_whole(self.resolution, "height_field.resolution", 4, example="128")

    @property
    def shape(self) -> tuple[int, int]:
        """(m, m)."""
        return (self.resolution, self.resolution)

    @property
    def cell_area(self) -> float:
        """Area a of one height sample, scene units^2: samples are spaced 2 W / (m - 1)."""
        return (2.0 * self.half_width / (self.resolution - 1)) ** 2

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(left, right, bottom, top) in scene units, for plots with origin='lower'."""
        w = self.half_width
        return (-w, w, -w, w)


@dataclass(frozen=True)
class Problem:
    """One reconstruction problem: recover d on ``grid`` from ``data`` through ``operator``.

    Attributes:
        operator: The forward model F: heights (m, m) -> image (c, n, n).
        data: Target b^delta (c, n, n), mask, volume, noise level, the print's design where the
            data carry one; never the ground truth of synthetic data (framework/core/truth.py).
        grid: Geometry of the heights.
        scene: Light, substrate, receiver, material and wavelengths (operators/scene.py).
    """

    operator: ImageOperator
    data: ReconstructionData
    grid: HeightGrid
    scene: Scene

    def __post_init__(self) -> None:
        if tuple(self.data.mask.shape) != self.grid.shape:
            raise ValueError(f"the mask has shape {tuple(self.data.mask.shape)} but the height field is "
                             f"{self.grid.shape}; the mask must match the height field")
        if self.data.ground_truth is not None or any(shot.ground_truth is not None for shot in self.data.shots):
            raise ValueError("a problem never carries the ground truth of synthetic data: build it from "
                             "data.without_truth() and keep the truth for the metrics (framework/core/truth.py)")

    def shot(self, index: int) -> Problem:
        """Shot ``index`` of a stack (framework/stack/stack_data.py) alone, through its own
        operator and scene, with the stack's design."""
        operator = self.operator.shots[index]
        shot = self.data.shots[index]
        if shot.design is None and self.data.design is not None:
            shot = replace(shot, design=self.data.design)
        return Problem(operator, shot, self.grid, operator.scene)

    def for_start(self) -> Problem:
        """The problem a start reads: this one, or for a stack of shots the one shot
        ``data.start_shot``."""
        return self.shot(self.data.start_shot) if self.data.shots else self

    @cached_property
    def fidelity(self) -> DataFidelity:
        """f(d) = 1/2 ||F(d) - b||_W^2 / (||b||_W^2 a), in the operator's dtype (framework/core/objective.py)."""
        return DataFidelity(self.operator, self.data.target.to(self.operator.dtype), cell_area=self.grid.cell_area,
                            weights=self.data.weights)

    @cached_property
    def context(self) -> RegularizerContext:
        """What the regularisers know: the mask, the volume, the cell area and the design (if given)."""
        return RegularizerContext(mask=self.data.mask, volume=self.data.volume, pixel_area=self.grid.cell_area,
                                  design=self.data.design)
