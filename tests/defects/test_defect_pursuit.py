"""The defect search on a photo that is the heights themselves (the image of h is h: every defect is
seen exactly, renders cost nothing): two defects of a print joined by a faint deviation are found as
two, each of its own kind and place; the evidence needed from the result's misfit."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from experiments.defect_prints import apply_defect, feature_sites
from framework.core.shapes import make_shape
from framework.defects.pursuit import Search, find_defects
from framework.pipeline.defect_stage import DefectSettings, evidence_needed

M = 64
CELL_MM = 50.0 / (M - 1)
MM_PER_UNIT = 25.0
NOISE = 1e-3  # the pixel noise of the photo of h, scene units


class HeightsPhoto:
    """The misfit of heights h against a photo that shows the print itself: ||h - print||^2."""

    def __init__(self, printed: torch.Tensor) -> None:
        self.printed = printed

    def residual(self, heights: torch.Tensor) -> torch.Tensor:
        return heights.double() - self.printed

    def __call__(self, heights: torch.Tensor) -> float:
        return float((self.residual(heights) ** 2).sum())


def _search() -> Search:
    return Search(z_min=3.0, grow=2.0, cluster_mm=1.5, min_evidence=50.0, max_fits=5, evaluations=40,
                  cell_mm=CELL_MM, cell_area=(2.0 / (M - 1)) ** 2, mm_per_unit=MM_PER_UNIT)


def _found(design: np.ndarray, printed: np.ndarray, d: np.ndarray) -> list:
    z_map = np.full(design.shape, 0.02 * float(design.max()) / 3.0)
    photo = HeightsPhoto(torch.from_numpy(printed))
    defects, _ = find_defects(torch.from_numpy(d), photo(torch.from_numpy(d)), torch.from_numpy(design),
                              np.ones(design.shape, dtype=bool), z_map, photo, NOISE, _search())
    return defects


def test_two_defects_joined_by_a_faint_deviation_are_found_as_two() -> None:
    design = make_shape("print_lines", M)
    first, second = feature_sites(design, CELL_MM, 2, 16.0, np.random.default_rng(5))
    printed, gap = apply_defect(design, design, first, "interruption", 1.0, 3.0, CELL_MM, MM_PER_UNIT)
    printed, high = apply_defect(design, printed, second, "too_high", -0.3, 6.0, CELL_MM, MM_PER_UNIT)
    # the reconstruction: the print plus a faint deviation (1.5% of the peak) that joins the two
    rows, cols = np.mgrid[0:M, 0:M]
    (r0, c0), (r1, c1) = first, second
    along = ((rows - r0) * (r1 - r0) + (cols - c0) * (c1 - c0)) / float((r1 - r0) ** 2 + (c1 - c0) ** 2)
    across = np.abs((rows - r0) * (c1 - c0) - (cols - c0) * (r1 - r0)) / math.hypot(r1 - r0, c1 - c0)
    bridge = (along >= 0) & (along <= 1) & (across <= 1.5)
    d = printed + 0.015 * float(design.max()) * bridge
    defects = _found(design, printed, d)
    assert sorted(defect.kind for defect in defects) == ["interruption", "too_high"]
    for planned in (gap, high):
        found = next(defect for defect in defects if defect.kind == planned.kind)
        assert math.hypot(found.x_mm - planned.x_mm, found.y_mm - planned.y_mm) <= 0.5 + 0.1 * planned.length_mm
    found_high = next(defect for defect in defects if defect.kind == "too_high")
    assert found_high.size == pytest.approx(-0.3, abs=0.06)
    assert all(defect.evidence >= 50.0 for defect in defects)


def test_a_print_equal_to_its_design_gives_no_defect() -> None:
    design = make_shape("print_lines", M)
    assert _found(design, design, design.copy()) == []


def test_the_evidence_needed_is_a_share_of_the_misfit_beyond_the_noise() -> None:
    settings = DefectSettings(min_evidence=50.0, model_error_share=0.1)
    assert evidence_needed(1000.0 * 4.0, 2.0, 1000, settings) == 50.0  # at the noise level: the floor
    # a model error of 8000 (image units^2) beyond the noise of 1000 pixels: a tenth of it, in noise variances;
    # half the noise asks four times the evidence, as a defect's own evidence grows
    assert evidence_needed(1000.0 * 4.0 + 8000.0, 2.0, 1000, settings) == pytest.approx(200.0)
    assert evidence_needed(1000.0 * 1.0 + 8000.0, 1.0, 1000, settings) == pytest.approx(800.0)
