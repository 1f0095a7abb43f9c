"""Defects read from tracks against their nominal profiles: each kind found at its place with its
size; changes within the tolerances and below the confidence are not reported; a blob of glass off
the beads, or a drop the search placed, is excess material of its volume."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from framework.tracks.track_defects import TrackTolerances, drop_defects, track_defects
from framework.tracks.track_set import Track, TrackSet

KNOTS = 41  # one knot per mm along a 40 mm path


def _line(y: float) -> Track:
    return Track(f"line {y:g}", np.array([[-20.0, y], [20.0, y]]), np.full(KNOTS, 0.5), np.full(KNOTS, 0.8),
                 np.zeros(KNOTS))


def _changed(track: Track, key: str, knots: slice, factor: float = 1.0, shift: float = 0.0) -> Track:
    values = getattr(track, key).copy()
    values[knots] = values[knots] * factor + shift
    return replace(track, **{key: values})


PLANTED = [  # (track, profile, knots, factor, shift, kind, x mm, size)
    (0, "height", slice(5, 8), 0.0, 0.0, "interruption", -14.0, 1.0),
    (0, "height", slice(20, 25), 0.6, 0.0, "too_low", 2.0, 0.4),
    (1, "height", slice(10, 14), 1.3, 0.0, "too_high", -8.5, -0.3),
    (1, "width", slice(25, 31), 1.4, 0.0, "too_wide", 7.5, 0.4),
    (2, "width", slice(3, 7), 0.7, 0.0, "too_narrow", -15.5, -0.3),
    (2, "offset", slice(28, 34), 1.0, 0.6, "displaced", 10.5, 0.6),
]


def test_each_kind_of_deviation_is_found_at_its_place_with_its_size() -> None:
    nominal = TrackSet(tuple(_line(y) for y in (-10.0, 0.0, 10.0)))
    tracks = list(nominal.tracks)
    for index, key, knots, factor, shift, *_ in PLANTED:
        tracks[index] = _changed(tracks[index], key, knots, factor, shift)
    tracks[2] = _changed(tracks[2], "height", slice(15, 17), 1.1)  # within the tolerance
    defects = track_defects(nominal, TrackSet(tuple(tracks)), TrackTolerances(), lambda run: 10.0)
    assert len(defects) == len(PLANTED)
    for index, _, knots, _, shift, kind, x, size in PLANTED:
        y = (-10.0, 0.0, 10.0)[index] + shift
        found = [d for d in defects if d.kind == kind]
        assert len(found) == 1, kind
        assert np.hypot(found[0].x_mm - x, found[0].y_mm - y) < 1.5, kind
        assert found[0].size == pytest.approx(size, rel=0.05), kind
        assert found[0].length_mm == pytest.approx(knots.stop - knots.start, abs=1e-9), kind


def test_a_deviation_the_photo_cannot_confirm_is_not_reported() -> None:
    nominal = TrackSet((_line(0.0),))
    fitted = TrackSet((_changed(nominal.tracks[0], "height", slice(10, 14), 0.5),))
    assert len(track_defects(nominal, fitted, TrackTolerances(), lambda run: 10.0)) == 1
    assert track_defects(nominal, fitted, TrackTolerances(z_min=3.0), lambda run: 2.0) == []


def test_a_blob_off_the_beads_is_excess_of_its_volume() -> None:
    m, cell = 128, 0.2
    axis = (np.arange(m) - (m - 1) / 2) * cell
    x, y = np.meshgrid(axis, axis)
    blob = 0.2 * np.clip(1 - ((x - 3.0) ** 2 + (y + 2.0) ** 2) / 0.8**2, 0.0, None) ** 1.5  # mm
    volume = blob.sum() * cell**2
    (drop,) = drop_defects(blob, cell, TrackTolerances(min_drop_mm3=0.05), lambda where: 5.0)
    assert drop.kind == "excess"
    assert (drop.x_mm, drop.y_mm) == pytest.approx((3.0, -2.0), abs=0.05)
    assert drop.size == pytest.approx(volume, rel=0.02)
    assert drop_defects(blob, cell, TrackTolerances(min_drop_mm3=2 * volume), lambda where: 5.0) == []


def test_a_placed_drop_is_excess_of_its_volume_when_the_photo_confirms_it() -> None:
    from framework.tracks.track_defects import placed_drop_defects
    from framework.tracks.track_set import Drop

    drops = [Drop(3.0, -4.0, 0.5, 0.4), Drop(8.0, 8.0, 0.2, 0.1), Drop(-6.0, 2.0, 0.6, 0.3)]
    found = placed_drop_defects(drops, TrackTolerances(), lambda i: (50.0, 50.0, 2.0)[i])
    # the second holds 0.025 mm^3 (under min_drop_mm3), the third is under z_min
    assert len(found) == 1
    defect = found[0]
    assert defect.kind == "excess" and (defect.x_mm, defect.y_mm) == (3.0, -4.0)
    assert defect.volume_mm3 == pytest.approx(2.0 * np.pi * 0.25 * 0.4)
    assert defect.length_mm == pytest.approx(2.355 * 0.5, rel=1e-3)


def test_an_opened_gap_is_an_interruption_at_its_place_and_length() -> None:
    from framework.tracks.track_defects import gap_defects

    fitted = TrackSet((_line(0.0), _line(6.0)))
    opened = [(1, 12.0, 2.0), (0, 30.0, 0.1)]  # a 2 mm gap 12 mm along the second line; one too short to count
    found = gap_defects(fitted, opened, TrackTolerances(), lambda i: 40.0)
    assert len(found) == 1
    defect = found[0]
    assert defect.kind == "interruption" and defect.length_mm == 2.0
    assert (defect.x_mm, defect.y_mm) == pytest.approx((-8.0, 6.0), abs=0.06)
    assert defect.volume_mm3 == pytest.approx(-0.5 * 0.8 * fitted.tracks[1].area_factor() * 2.0)
