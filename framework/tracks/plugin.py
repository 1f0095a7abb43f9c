"""The representation plugin ``tracks``: the print's beads from its tool path or its design,
rendered onto the heights grid (framework/tracks/track_heights.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from torch import Tensor

from framework.tracks.from_design import profiles_drawing, tracks_from_design
from framework.tracks.toolpath import read_toolpath
from framework.tracks.track_heights import TrackHeights, TrackSettings
from operators.values import checked_number, checked_whole

__all__ = ["TracksRepresentation"]


class TracksRepresentation(TrackHeights):
    """The registered ``tracks`` representation: :class:`TrackHeights` built from the config."""

    @staticmethod
    def example_settings() -> dict[str, Any]:
        """Settings of the contract checks (a problem whose design has beads)."""
        return {"knot_mm": 2.0, "residual_mm": 5.0}

    @classmethod
    def from_config(cls, **settings: Any) -> Any:
        """See :func:`tracks_builder`."""
        return tracks_builder(**settings)


def tracks_builder(toolpath: str | None = None, width_mm: float | None = None, height_mm: float | None = None,
                          fibre_diameter_mm: float | None = None, knot_mm: float = 1.0, max_offset_mm: float = 1.5,
                          width_range: tuple[float, float] | list[float] = (0.25, 2.5), height_factor: float = 3.0,
                          residual_mm: float = 1.0, smoothness: float = 1.0e-4,
                          residual_sparsity: float = 1.0e-2, spare_drops: int = 0, gaps: int = 0,
                          anchored: bool = True) -> Any:
    """The ``representation`` group's keys for tracks: ``toolpath`` (a .csv or G-code file, mm,
    framework/tracks/toolpath.py; with a design too, its profiles and shapes are fitted to the
    design; null: the skeleton of the data's design, framework/tracks/from_design.py), the G-code's
    bead size where it gives none, :class:`TrackSettings`, and ``anchored``: with a design, what the
    nominal beads do not draw of it (design - R(theta_0)) is added to every render, so that the
    start is the design itself and the beads carry only the print's deviations from it.
    Returns a builder (problem, d0) -> TracksRepresentation."""
    for key, value in (("knot_mm", knot_mm), ("max_offset_mm", max_offset_mm), ("height_factor", height_factor)):
        checked_number(value, f"solver.representation.{key}", above=0.0)
    for key, value in (("residual_mm", residual_mm), ("smoothness", smoothness),
                       ("residual_sparsity", residual_sparsity)):
        checked_number(value, f"solver.representation.{key}", 0.0)
    low, high = (float(v) for v in width_range)
    if not 0.0 < low < 1.0 < high:
        raise ValueError(f"solver.representation.width_range={list(width_range)} must be [low < 1, high > 1] "
                         "(factors of each bead's nominal width), e.g. [0.25, 2.5]")
    checked_whole(spare_drops, "solver.representation.spare_drops", 0)
    checked_whole(gaps, "solver.representation.gaps", 0)
    settings = TrackSettings(knot_mm, max_offset_mm, (low, high), height_factor, residual_mm, smoothness,
                             residual_sparsity, spare_drops, gaps)
    given = None if toolpath is None else read_toolpath(Path(toolpath).expanduser(), width_mm, height_mm,
                                                         fibre_diameter_mm)

    def build(problem: Any, d0: Tensor) -> TrackHeights:
        grid, mm = problem.grid, problem.scene.mm_per_unit
        tracks, design = given, problem.data.design
        if tracks is not None and design is not None:  # the tool path's paths, the design's cross-sections
            tracks = profiles_drawing(tracks, design.detach().cpu().double().numpy(), grid.half_width, mm, settings)
        if tracks is None:
            if design is None:
                raise ValueError("representation tracks needs the print's tool path (solver.representation.toolpath="
                                 "path.csv or .gcode) or its design (height_field.path with data=file/photo, "
                                 "data.printed with synthetic data)")
            tracks = tracks_from_design(design.detach().cpu().double().numpy(), grid.half_width, mm, settings)
        source = f"the tool path {Path(toolpath).name}" if toolpath is not None else "the design's skeleton"
        mask = problem.data.mask.detach().cpu().numpy() > 0
        representation = TracksRepresentation(tracks, grid.resolution, grid.half_width, mm, settings, d0.dtype, source,
                                              mask)
        if anchored and design is not None:
            representation.correction = design.to(d0.dtype) - representation.heights(representation.initial())
        return representation

    return build
