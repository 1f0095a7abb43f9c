"""The profile search of the screen blur's width (framework/lab/width_search.py) on misfit
curves with known minima."""

from __future__ import annotations

import math

import pytest

from framework.lab.width_search import MIN_RISE, search_width


def _curve(true_px: float, skew: float = 0.0):
    """A misfit with its minimum 0.02 at ``true_px``, quadratic (plus a cubic skew) in log width;
    the widths it was called with are kept in ``calls``."""
    calls: list[float] = []

    def misfit(width: float) -> float:
        calls.append(width)
        x = math.log(width / true_px)
        return 0.02 + 0.05 * x * x + skew * x ** 3

    return misfit, calls


@pytest.mark.parametrize("true_px", [0.3, 0.5, 0.9, 1.5, 2.2])
def test_a_parabola_in_log_width_is_found_in_a_few_fits(true_px: float) -> None:
    misfit, calls = _curve(true_px)
    profile = search_width(misfit)
    assert profile.width == pytest.approx(true_px, rel=1e-6)  # the vertex of an exact parabola
    assert profile.identified and profile.at_bound == ""
    assert profile.rise == pytest.approx(0.05 * math.log(2.0) ** 2 / misfit(profile.width), rel=1e-3)
    assert len(calls) <= 7 and calls[:4] == [0.35, 0.7, 1.4, 2.8]


@pytest.mark.parametrize("true_px", [0.5, 1.5])
def test_a_skewed_minimum_is_found_within_the_tolerance(true_px: float) -> None:
    misfit, calls = _curve(true_px, skew=0.02)
    profile = search_width(misfit, tolerance=0.02)
    assert profile.width == pytest.approx(true_px, rel=0.05)
    assert profile.misfits == [misfit(w) for w in profile.widths] and len(calls) <= 9 + len(profile.widths)


def test_the_grid_is_extended_where_the_minimum_lies_at_its_edge() -> None:
    misfit, calls = _curve(5.0)
    profile = search_width(misfit, upper=12.0)
    assert 5.6 in calls and profile.width == pytest.approx(5.0, rel=1e-6) and profile.identified
    misfit, calls = _curve(0.25)
    assert search_width(misfit).width == pytest.approx(0.25, rel=1e-6) and 0.175 in calls


def test_a_minimum_at_a_bound_or_a_flat_profile_is_not_told() -> None:
    falling = search_width(lambda w: 0.04 + 0.001 * w)  # less blur always fits better
    assert falling.at_bound == "lower" and falling.width == pytest.approx(0.175) and not falling.identified
    rising = search_width(lambda w: 0.04 - 0.001 * w, upper=8.0)
    assert rising.at_bound == "upper" and rising.width == pytest.approx(5.6) and not rising.identified
    flat = search_width(lambda w: 0.04 + 1e-4 * math.log(w) ** 2)
    assert flat.at_bound == "" and 0 < flat.rise < MIN_RISE and not flat.identified


@pytest.mark.parametrize("grid", [(0.5, 1.0), (0.0, 1.0, 2.0), (0.05, 1.0, 2.0), (1.0, 2.0, 16.0)])
def test_a_bad_grid_is_refused(grid: tuple[float, ...]) -> None:
    with pytest.raises(ValueError, match="width grid"):
        search_width(lambda w: w, grid)


@pytest.mark.parametrize("tolerance", [0.0, -0.1, 1.5])
def test_a_bad_tolerance_is_refused(tolerance: float) -> None:
    with pytest.raises(ValueError, match="tolerance"):
        search_width(lambda w: w, tolerance=tolerance)
