"""Tracks drawn onto the heights grid against independent truths: the bead family's area and
half-height width by quadrature and by reading the rendered grid, the volume of a drawn bead, and
a design drawn as melted glass (experiments/paper/fibre_print.py) turned back into its tool path, beads
whose tails meet kept apart, and tracks anchored to a design starting at it."""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from scipy import integrate

from experiments.paper.fibre_print import TOOLPATH, polyline_distance, draw_beads
from framework.core.problem import HeightGrid
from framework.tracks.from_design import tracks_from_design
from framework.tracks.plugin import tracks_builder
from framework.tracks.track_heights import TrackHeights, TrackSettings
from framework.tracks.track_set import Track, TrackSet, bead_area_factor

MM = 25.0  # mm per scene unit; the grid spans [-25, 25] mm


def _profile(v: float, shape: float) -> float:
    """The power cap at v = 2 r / width (framework/tracks/track_set.py), written out again."""
    p = 1.0 / shape
    c2 = 1.0 / (1.0 - 2.0 ** (-1.0 / p))
    return max(0.0, 1.0 - v * v / c2) ** p


@pytest.mark.parametrize("shape", [0.02, 0.5, 1.0, 2.0, 3.0])
def test_the_bead_family_has_its_half_height_at_the_width_and_its_area_in_closed_form(shape) -> None:
    assert _profile(1.0, shape) == pytest.approx(0.5, rel=1e-12)
    area = integrate.quad(lambda v: _profile(v, shape), -20.0, 20.0, limit=400, points=[-1.0, 1.0])[0] / 2.0
    assert bead_area_factor(shape) == pytest.approx(area, rel=1e-6)


def test_a_drawn_bead_has_its_height_width_and_volume() -> None:
    track = Track("line", np.array([[-15.0, 0.0], [15.0, 0.0]]), np.array([0.5]), np.array([1.2]), np.array([0.0]),
                  shape=1.5)
    rep = TrackHeights(TrackSet((track,)), 513, 1.0, MM, TrackSettings(residual_mm=0.0))
    d = rep.heights(rep.initial()).numpy() * MM
    column = d[:, 256]  # x = 0, across the bead
    assert column.max() == pytest.approx(0.5, rel=1e-3)
    axis = np.linspace(-25.0, 25.0, 513)
    above = axis[column >= 0.25]
    assert above.max() - above.min() == pytest.approx(1.2, abs=2 * 50.0 / 512)
    cell = 50.0 / 512
    # Body and two round ends (a solid of revolution of the half profile: 2 pi int r z(r) dr)
    ends = 2 * math.pi * 0.5 * integrate.quad(lambda r: r * _profile(2 * r / 1.2, 1.5), 0.0, 5.0)[0]
    expected = 0.5 * 1.2 * bead_area_factor(1.5) * 30.0 + ends
    assert d.sum() * cell**2 == pytest.approx(expected, rel=5e-3)
    assert track.volume() == pytest.approx(0.5 * 1.2 * bead_area_factor(1.5) * 30.0, rel=1e-12)


def _length(points: list[tuple[float, float]]) -> float:
    return float(np.sum(np.hypot(*np.diff(np.asarray(points), axis=0).T)))


def test_a_design_of_melted_beads_gives_back_its_tool_path() -> None:
    m = 256
    design = draw_beads(m) / MM  # circular segments, not the model's family
    found = tracks_from_design(design, 1.0, MM, TrackSettings())
    # The two layers of the wall are one bead in a height field: five tracks besides it.
    planned = [t for t in TOOLPATH if t[0] != "wall_top"]
    assert len(found.tracks) == len(planned)
    for name, points, width, height in planned:
        best = min(found.tracks, key=lambda t: float(np.median(polyline_distance(t.path[:, 0], t.path[:, 1], points))))
        gap = polyline_distance(best.path[:, 0], best.path[:, 1], points)
        assert np.median(gap) < 0.15 and best.length > 0.9 * _length(points), name  # the skeleton on the tool path
        layers = 2 if name == "wall" else 1
        assert np.median(best.height) == pytest.approx(layers * height, rel=0.1), name
        assert np.median(best.width) == pytest.approx(width, rel=0.15), name
    rep = TrackHeights(found, m, 1.0, MM, TrackSettings(residual_mm=0.0))
    drawn = rep.heights(rep.initial()).numpy()
    assert np.linalg.norm(drawn - design) / np.linalg.norm(design) < 0.1


def _segment_beads(m: int, beads: list[tuple[tuple[float, float], tuple[float, float], float, float]]) -> np.ndarray:
    """Gaussian beads (heights h exp(-r^2 / 2 sigma^2) at distance r from a segment, so with round
    ends), in scene units on the (m, m) grid; each bead (start mm, end mm, height mm, full width at
    half height mm)."""
    axis = np.linspace(-MM, MM, m)
    x, y = np.meshgrid(axis, axis)
    design = np.zeros((m, m))
    for start, end, height, width in beads:
        a, b = np.asarray(start), np.asarray(end)
        t = np.clip(((x - a[0]) * (b - a)[0] + (y - a[1]) * (b - a)[1]) / float(np.sum((b - a) ** 2)), 0.0, 1.0)
        r2 = (x - a[0] - t * (b - a)[0]) ** 2 + (y - a[1] - t * (b - a)[1]) ** 2
        sigma = width / (2.0 * math.sqrt(2.0 * math.log(2.0)))
        design += height * np.exp(-r2 / (2.0 * sigma**2))
    return design / MM


def test_wide_beads_whose_tails_meet_stay_apart_and_reach_their_ends() -> None:
    beads = [((-6.0, -15.0), (-6.0, 15.0), 1.5, 5.0), ((6.0, -15.0), (6.0, 15.0), 1.0, 5.0),
             ((-20.0, 18.0), (-10.0, 18.0), 0.8, 1.2)]
    design = _segment_beads(128, beads)
    found = tracks_from_design(design, 1.0, MM, TrackSettings())
    assert len(found.tracks) == len(beads)  # no bridge through the tails, no fork at a wide end
    for start, end, _, width in beads:
        points = [start, end]
        best = min(found.tracks, key=lambda t: float(np.median(polyline_distance(t.path[:, 0], t.path[:, 1], points))))
        assert np.median(polyline_distance(best.path[:, 0], best.path[:, 1], points)) < 0.2
        ends = [float(np.min(np.hypot(*(best.path[[0, -1]] - np.asarray(p)).T))) for p in points]
        assert max(ends) < 0.1 * width + 0.4, (start, ends)  # the path runs to the bead's end, not half a width short
    rep = TrackHeights(found, 128, 1.0, MM, TrackSettings(residual_mm=0.0))
    drawn = rep.heights(rep.initial()).numpy()
    assert np.linalg.norm(drawn - design) / np.linalg.norm(design) < 0.05


def test_a_gap_cuts_its_length_out_of_the_bead(tmp_path) -> None:
    track = Track("line", np.array([[-15.0, 0.0], [15.0, 0.0]]), np.array([0.5]), np.array([1.2]), np.array([0.0]),
                  gaps=((15.0, 3.0),))  # 3 mm around x = 0
    whole = TrackHeights(TrackSet((replace(track, gaps=()),)), 513, 1.0, MM, TrackSettings(residual_mm=0.0))
    cut = TrackHeights(TrackSet((track,)), 513, 1.0, MM, TrackSettings(residual_mm=0.0))
    d, full = (r.heights(r.initial()).numpy() * MM for r in (cut, whole))
    assert d[:, 256].max() < 1e-6 and d[:, 256 + 31].max() == pytest.approx(0.5, rel=1e-3)  # x = 0 and 3 mm
    cell = 50.0 / 512
    missing = 0.5 * 1.2 * bead_area_factor(1.0) * 3.0  # the logistic ends cut exactly the gap's length
    assert (full.sum() - d.sum()) * cell**2 == pytest.approx(missing, rel=5e-3)
    assert replace(track, gaps=()).volume() - track.volume() == pytest.approx(missing, rel=1e-12)
    TrackSet((track,)).save(tmp_path / "tracks.json")
    assert TrackSet.load(tmp_path / "tracks.json").tracks[0].gaps == ((15.0, 3.0),)


def test_the_vjp_is_the_adjoint_of_the_drawing_with_drops_and_residual() -> None:
    from framework.tracks.track_set import Drop

    arc = np.stack([8 * np.cos(np.linspace(0, 3, 40)), 8 * np.sin(np.linspace(0, 3, 40))], axis=1)
    tracks = TrackSet((Track("arc", arc, np.linspace(0.3, 0.6, 9), np.array([0.8]), np.array([0.1]), 1.0,
                             gaps=((10.0, 2.0),)),), (Drop(3.0, -4.0, 0.6, 0.2),))
    rep = TrackHeights(tracks, 128, 1.0, MM, TrackSettings(residual_mm=4.0, gaps=1, spare_drops=1))
    theta = rep.initial() + 0.01 * rep.scale() * torch.randn(rep.size, generator=torch.Generator().manual_seed(3),
                                                             dtype=torch.float64)
    g = torch.randn(128, 128, generator=torch.Generator().manual_seed(4), dtype=torch.float64)
    v = torch.randn(rep.size, generator=torch.Generator().manual_seed(5), dtype=torch.float64) * rep.scale()
    eps = 1e-6
    moved = (rep.heights(theta + eps * v) - rep.heights(theta - eps * v)) / (2 * eps)
    assert float(torch.sum(moved * g)) == pytest.approx(float(torch.sum(v * rep.vjp(theta, g))), rel=1e-6)


def test_a_float32_fit_at_a_bound_reads_back_as_tracks() -> None:
    track = Track("line", np.array([[-10.0, 0.0], [10.0, 0.0]]), np.array([0.5]), np.array([1.0]), np.array([0.0]))
    rep = TrackHeights(TrackSet((track,)), 64, 1.0, MM, TrackSettings(residual_mm=0.0), dtype=torch.float32)
    lower, _ = rep.bounds()
    fitted = rep.track_set(lower.clone())  # every parameter at its lower bound, in float32
    assert fitted.tracks[0].shape >= 0.02 and np.all(fitted.tracks[0].height == 0.0)


def test_anchored_tracks_start_at_the_design_and_keep_their_jacobian() -> None:
    m = 96
    design = _segment_beads(m, [((-10.0, -8.0), (10.0, 8.0), 0.9, 1.5), ((-12.0, 10.0), (12.0, 10.0), 0.6, 1.0)])
    problem = SimpleNamespace(grid=HeightGrid(m, 1.0, 0.1), scene=SimpleNamespace(mm_per_unit=MM),
                              data=SimpleNamespace(design=torch.from_numpy(design), mask=torch.ones(m, m)))
    d0 = torch.zeros(m, m, dtype=torch.float64)
    plain = tracks_builder(anchored=False)(problem, d0)
    anchored = tracks_builder(anchored=True)(problem, d0)
    theta = anchored.initial()
    assert torch.allclose(anchored.heights(theta), torch.from_numpy(design), atol=1e-12)
    assert not torch.allclose(plain.heights(theta), torch.from_numpy(design), atol=1e-4)  # beads alone miss some
    g = torch.from_numpy(np.random.default_rng(0).standard_normal((m, m)))
    moved = theta + 0.01 * plain.scale()
    assert torch.allclose(anchored.vjp(moved, g), plain.vjp(moved, g))  # a constant added: the same J^T
    assert torch.allclose(anchored.heights(moved) - plain.heights(moved), anchored.correction)
