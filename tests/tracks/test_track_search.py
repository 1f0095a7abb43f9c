"""The global search of a track's windows finds what the gradient cannot reach: a bead moved by
more than its width, and an interruption, against heights as the objective (the search needs no
caustic to be checked; it only compares objective values)."""

from __future__ import annotations

import numpy as np
import torch

from framework.tracks.track_heights import TrackHeights, TrackSettings
from framework.tracks.track_search import SearchSettings, search_tracks
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
    misfit = ((rep.heights(theta) - target) ** 2).reshape(-1).numpy()
    found, changes = search_tracks(theta, rep._search_windows(1.0, M), rep.profile_slices, lambda t: 0.8 / MM,
                                   rep.clipped, objective, misfit, 1e-12, SearchSettings())
    assert changes
    moved = found[offsets].numpy() * MM
    assert np.all(moved[9:12] > 0.3)  # the window over the moved stretch went across
    assert np.all(found[heights].numpy()[28:30] * MM < 0.1)  # and the gap opened (its last knot half: a window edge)
    assert objective(found) < 0.3 * objective(theta)
