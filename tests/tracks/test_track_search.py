"""The global search finds what the gradient cannot reach: a bead moved by
more than its width, and an interruption, against heights as the objective (the search needs no
caustic to be checked; it only compares objective values)."""

from __future__ import annotations

import numpy as np
import torch

from framework.tracks.track_heights import TrackHeights, TrackSettings
from framework.core.contracts.representation import SearchContext
from framework.tracks.track_set import Track, TrackSet

MM, M = 25.0, 128


def _line(offset: np.ndarray, height: np.ndarray) -> TrackSet:
    return TrackSet((Track("line", np.array([[-20.0, 0.0], [20.0, 0.0]]), height, np.full(41, 0.8), offset),))


def test_the_search_moves_a_bead_beyond_its_width_and_opens_a_gap() -> None:
    nominal = _line(np.zeros(41), np.full(41, 0.5))
    truth_offset, truth_height = np.zeros(41), np.full(41, 0.5)
    truth_offset[8:13] = 0.8  # one bead width aside over 5 mm: no overlap with the nominal bead
    truth_height[28:31] = 0.0  # a 3 mm gap
    rep = TrackHeights(nominal, M, 1.0, MM, TrackSettings(residual_mm=0.0))
    truth = TrackHeights(_line(truth_offset, truth_height), M, 1.0, MM, TrackSettings(residual_mm=0.0))
    target = truth.heights(truth.initial())

    def objective(theta: torch.Tensor) -> float:
        return float(torch.sum((rep.heights(theta) - target) ** 2))

    theta = rep.initial()
    heights, _, offsets = rep.profile_slices(0)
    # The gradient at the nominal bead says nothing of the moved one: they do not overlap.
    gradient = rep.vjp(theta, rep.heights(theta) - target)
    assert float(gradient[offsets][9:12].abs().max()) < 1e-6 * float(gradient.abs().max())
    # The receiver stands under the glass: its pixels are the grid's samples.
    def misfit(theta: torch.Tensor) -> np.ndarray:
        return ((rep.heights(theta) - target) ** 2).reshape(-1).numpy()

    found, changes = rep.search(theta, SearchContext(objective, misfit, lambda theta: 0.0, 1e-12, 1.0, M))
    assert changes
    moved = found[offsets].numpy() * MM
    assert np.all(moved[9:12] > 0.3)  # the window over the moved stretch went across
    assert np.all(found[heights].numpy()[28:30] * MM < 0.1)  # and the gap opened (its last knot half: a window edge)
    assert objective(found) < 0.3 * objective(theta)


def test_the_search_places_a_drop_off_the_beads() -> None:
    from framework.tracks.track_set import Drop

    nominal = _line(np.zeros(41), np.full(41, 0.5))
    settings = TrackSettings(residual_mm=0.0, spare_drops=2)
    rep = TrackHeights(nominal, M, 1.0, MM, settings)
    truth = TrackHeights(TrackSet(nominal.tracks, (Drop(6.0, 8.0, 0.5, 0.35),)), M, 1.0, MM,
                         TrackSettings(residual_mm=0.0))
    target = truth.heights(truth.initial())

    def objective(theta: torch.Tensor) -> float:
        return float(torch.sum((rep.heights(theta) - target) ** 2))

    def misfit(theta: torch.Tensor) -> np.ndarray:
        return ((rep.heights(theta) - target) ** 2).reshape(-1).numpy()

    theta = rep.initial()
    assert rep.placed_drops(theta) == []
    found, changes = rep.search(theta, SearchContext(objective, misfit, lambda theta: 0.0, 1e-12, 1.0, M))
    placed = rep.placed_drops(found)
    assert len(placed) == 1 and any("drop" in change for change in changes)
    drop = placed[0][1]
    assert np.hypot(drop.x - 6.0, drop.y - 8.0) < 0.5  # within a receiver pixel and a half (0.39 mm)
    assert objective(found) < 0.5 * objective(theta)


def test_a_later_search_opens_a_sharp_gap_where_the_bead_is_interrupted() -> None:
    from dataclasses import replace

    nominal = _line(np.zeros(41), np.full(41, 0.5))
    truth = TrackHeights(TrackSet((replace(nominal.tracks[0], gaps=((24.0, 2.0),)),)), M, 1.0, MM,
                         TrackSettings(residual_mm=0.0))
    target = truth.heights(truth.initial())
    rep = TrackHeights(nominal, M, 1.0, MM, TrackSettings(residual_mm=0.0, gaps=1))

    def objective(theta: torch.Tensor) -> float:
        return float(torch.sum((rep.heights(theta) - target) ** 2))

    def misfit(theta: torch.Tensor) -> np.ndarray:
        return ((rep.heights(theta) - target) ** 2).reshape(-1).numpy()

    theta = rep.initial()
    assert rep.track_set(theta).tracks[0].gaps == ()  # a closed gap cuts nothing
    first, _ = rep.search(theta, SearchContext(objective, misfit, lambda theta: 0.0, 1e-12, 1.0, M, earlier=0))
    assert rep.track_set(first).tracks[0].gaps == ()  # the first search leaves gaps to later ones
    found, changes = rep.search(theta, SearchContext(objective, misfit, lambda theta: 0.0, 1e-12, 1.0, M, earlier=1))
    (centre, length), = rep.track_set(found).tracks[0].gaps
    assert abs(centre - 24.0) <= 0.5 and abs(length - 2.0) <= 0.5, (centre, length, changes)
    assert objective(found) < 0.2 * objective(theta)
