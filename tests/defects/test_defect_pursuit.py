"""The defect search on a photo that is the heights themselves (the image of h is h: every defect is
seen exactly, renders cost nothing): two defects of a print joined by a faint deviation are found as
two, each of its own kind and place; two pieces of one long defect are joined, two defects with glass
as designed between them are not; a line narrowed to less than half its width is interrupted; the
evidence needed from the result's misfit; the tolerance."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from experiments.paper.defect_prints import apply_defect, feature_sites
from framework.scene.printed_shapes import make_shape
from framework.defects.fit import Defect, Fit, fit_candidate, frame_of
from framework.defects.models import apply_model
from framework.defects.pursuit import Search, _joined, find_defects
from framework.defects.regions import Candidate
from framework.defects.defect_stage import DefectSettings, evidence_needed

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


def _pieces(design: np.ndarray, printed: np.ndarray, site: tuple[int, int], pieces: list[tuple[float, float]]) -> list:
    """Fits of a raised line (a third too high) over each (centre, length) in mm along the feature at
    ``site``, each on top of those before, against the photo of ``printed``."""
    photo = HeightsPhoto(torch.from_numpy(printed))
    frame = frame_of(design, Candidate(np.array([site[0]]), np.array([site[1]]), np.array([1.0])), CELL_MM)
    fits, base = [], torch.from_numpy(design)
    for centre_mm, length_mm in pieces:
        params = (centre_mm / CELL_MM, length_mm / CELL_MM, -0.3)
        heights = apply_model(base, frame, "modulation", params, _search().cell_area)
        piece = Defect("too_high", 0.0, 0.0, length_mm, -0.3, 0.0, 0.0, 1e4, 1.0, "modulation", params)
        fits.append(Fit(piece, frame, heights, photo(heights)))
        base = heights
    return fits


def test_two_pieces_of_one_long_defect_are_joined_two_defects_apart_are_not() -> None:
    design = make_shape("print_lines", M)
    site = feature_sites(design, CELL_MM, 1, 16.0, np.random.default_rng(3))[0]
    printed, planned = apply_defect(design, design, site, "too_high", -0.3, 8.0, CELL_MM, MM_PER_UNIT)
    photo = HeightsPhoto(torch.from_numpy(printed))
    pieces = _pieces(design, printed, site, [(-2.0, 4.0), (2.0, 4.0)])
    joined, at = _joined(pieces, torch.from_numpy(design), pieces[-1].misfit, photo, NOISE, _search())
    assert len(joined) == 1
    assert joined[0].defect.kind == "too_high" and joined[0].defect.size == pytest.approx(-0.3, abs=0.05)
    assert joined[0].defect.length_mm == pytest.approx(planned.length_mm, abs=1.0)
    assert at <= pieces[-1].misfit + 50.0 * NOISE ** 2
    # two raised stretches 2 mm long with 2.5 mm of the line as designed between them stay two
    (along_r, along_c) = frame_of(design, Candidate(np.array([site[0]]), np.array([site[1]]), np.array([1.0])),
                                  CELL_MM).along
    offset = 2.25 / CELL_MM
    two = design
    for sign in (-1.0, 1.0):
        at_site = (int(round(site[0] + sign * offset * along_r)), int(round(site[1] + sign * offset * along_c)))
        two, _ = apply_defect(design, two, at_site, "too_high", -0.3, 2.0, CELL_MM, MM_PER_UNIT)
    pieces = _pieces(design, two, site, [(-2.25, 2.0), (2.25, 2.0)])
    kept, _ = _joined(pieces, torch.from_numpy(design), pieces[-1].misfit, HeightsPhoto(torch.from_numpy(two)), NOISE,
                      _search())
    assert len(kept) == 2


def test_a_line_narrowed_to_less_than_half_its_width_is_interrupted() -> None:
    design = make_shape("print_lines", M)
    site = feature_sites(design, CELL_MM, 1, 16.0, np.random.default_rng(7))[0]
    printed, planned = apply_defect(design, design, site, "too_narrow", -0.7, 3.0, CELL_MM, MM_PER_UNIT)
    photo = HeightsPhoto(torch.from_numpy(printed))
    e = printed - design
    rows, cols = np.nonzero(np.abs(e) >= 0.05 * float(np.abs(e).max()))
    design_t = torch.from_numpy(design)
    fit = fit_candidate(design_t, design_t, Candidate(rows, cols, e[rows, cols]), photo, photo(design_t), NOISE,
                        _search().cell_area, CELL_MM, MM_PER_UNIT, 40)
    assert fit.defect.kind == "interruption" and fit.defect.size >= 0.5
    assert math.hypot(fit.defect.x_mm - planned.x_mm, fit.defect.y_mm - planned.y_mm) <= 1.0


def test_changes_within_the_tolerance_are_not_defects() -> None:
    settings = DefectSettings(tolerance=0.05, tolerance_mm=0.1)

    def defect(kind: str, size: float) -> Defect:
        return Defect(kind, 0.0, 0.0, 3.0, size, 0.0, 0.0, 1e4, 1.0, "modulation", (0.0, 1.0, size))

    for kind, size, within in (("too_low", 0.04, True), ("too_high", -0.04, True), ("too_low", 0.06, False),
                               ("too_narrow", -0.03, True), ("too_wide", 0.2, False), ("displaced", 0.05, True),
                               ("displaced", 0.2, False), ("interruption", 0.01, False), ("excess", 0.01, False)):
        assert settings.within_tolerance(defect(kind, size)) == within, (kind, size)
    assert not DefectSettings(tolerance=0.0, tolerance_mm=0.0).within_tolerance(defect("too_low", 0.01))
    with pytest.raises(ValueError, match="defects.tolerance=-0.1"):
        DefectSettings.parse({"tolerance": -0.1})



def test_a_cut_through_a_round_bump_is_found_in_the_frame_its_deviation_shows() -> None:
    # a round bump has no direction of its own; the cut runs wherever the printer cut it
    design = make_shape("bump", M)
    site = feature_sites(design, CELL_MM, 1, 16.0, np.random.default_rng(1))[0]
    printed, planned = apply_defect(design, design, site, "interruption", 1.0, 2.0, CELL_MM, MM_PER_UNIT)
    defects = _found(design, printed, printed.copy())
    assert defects and defects[0].kind == "interruption"
    assert math.hypot(defects[0].x_mm - planned.x_mm, defects[0].y_mm - planned.y_mm) <= 1.5


class HeightsPhotoWithGradient(HeightsPhoto):
    """:class:`HeightsPhoto` with its gradient 2 (h - print) (J = I: every column norm is 1)."""

    def gradient(self, heights: torch.Tensor) -> torch.Tensor:
        return 2.0 * self.residual(heights)


def test_a_drop_the_reconstruction_does_not_show_is_found_from_the_photo() -> None:
    design = make_shape("print_lines", M)
    (site,) = feature_sites(design, CELL_MM, 1, 16.0, np.random.default_rng(3))
    printed, drop = apply_defect(design, design, site, "excess", 0.3, 0.0, CELL_MM, MM_PER_UNIT)
    photo = HeightsPhotoWithGradient(torch.from_numpy(printed))
    d = torch.from_numpy(design.copy())  # the reconstruction kept the design's basin: no deviation at all
    z_map = np.full(design.shape, 0.02 * float(design.max()) / 3.0)
    args = (d, photo(d), torch.from_numpy(design), np.ones(design.shape, dtype=bool), z_map, photo, NOISE, _search())
    assert find_defects(*args)[0] == []  # from the reconstruction alone: no candidate
    defects, tried = find_defects(*args, np.ones(design.shape))
    assert len(defects) == 1 and defects[0].kind == drop.kind and tried >= 1
    assert math.hypot(defects[0].x_mm - drop.x_mm, defects[0].y_mm - drop.y_mm) <= 0.5
    assert defects[0].size == pytest.approx(drop.size, rel=0.3)
