"""Built-in height fields: facts derived from the formulas of docs/method.md, "Built-in height fields"."""

from __future__ import annotations

import math

import numpy as np
import pytest

from framework.scene.printed_shapes import SHAPES, g, grid, line_h, line_v, make_shape, oblique_lines

L1_PEAK = 1.0 / (0.5 * math.sqrt(2.0 * math.pi))  # max g(0.5, 0, .)
M = 121  # linspace(-1, 1, 121) holds x = 0, -0.5 and y = 0.75, 5/12 exactly (steps of 1/60)


def index(value: float, m: int = M) -> int:
    i = int(round((value + 1.0) / 2.0 * (m - 1)))
    assert abs(np.linspace(-1, 1, m)[i] - value) < 1e-12
    return i


@pytest.fixture(scope="module")
def lines() -> np.ndarray:
    return make_shape("print_lines", M)


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_every_shape_is_a_nonnegative_float64_square(name: str) -> None:
    d = make_shape(name, 32)
    assert d.shape == (32, 32) and d.dtype == np.float64
    assert np.isfinite(d).all() and d.min() >= 0.0


def test_print_lines_peak_is_a_tenth_of_max_g(lines: np.ndarray) -> None:
    assert lines.max() == pytest.approx(0.1 * L1_PEAK, rel=2e-3)


def test_print_lines_on_l1_equals_its_cross_section_peak(lines: np.ndarray) -> None:
    # (x, y) = (0, -0.5): X = 0 on l1, far (>= 3 in X, Y units) from every other line.
    assert lines[index(-0.5), index(0.0)] == pytest.approx(0.1 * L1_PEAK, rel=1e-6)


@pytest.mark.parametrize("y", [0.0, 5.0 / 12.0, 0.75], ids=["l4", "l5", "l6"])
def test_horizontal_lines_peak_like_l1(lines: np.ndarray, y: float) -> None:
    # l4 as is, l5 rescaled to max(l1), l6 with analytic peak 0.25 g(0.125, 0, 0) = g(0.5, 0, 0).
    assert lines[index(y), index(-0.5)] == pytest.approx(0.1 * L1_PEAK, rel=1e-3)


def test_l6_analytic_peak_equals_l1() -> None:
    assert 0.25 * g(0.125, 0.0, np.zeros(1))[0] == pytest.approx(g(0.5, 0.0, np.zeros(1))[0], rel=1e-14)


def test_print_lines_vanish_far_from_the_lines(lines: np.ndarray) -> None:
    for y, x in [(-1.0, -1.0), (-1.0, 1.0), (1.0, 1.0), (-0.5, -0.6), (1.0, -1.0), (-0.75, -0.6)]:
        assert lines[index(y), index(x)] < 1e-6


def test_print_lines_is_deterministic_across_calls(lines: np.ndarray) -> None:
    np.testing.assert_array_equal(make_shape("print_lines", M), lines)


def test_line_v_is_point_symmetric_and_line_h_its_transpose() -> None:
    x, y = grid(65)
    X, Y = 6 * x, 6 * y
    v = line_v(0.5, -3.0, 3.0, X, Y)
    np.testing.assert_allclose(v, v[::-1, ::-1], rtol=1e-12, atol=0)
    np.testing.assert_allclose(v, v[:, ::-1], rtol=1e-12, atol=0)
    np.testing.assert_allclose(line_h(0.5, -4.5, 2.0, X, Y), line_v(0.5, -4.5, 2.0, X, Y).T, rtol=1e-12)


def test_line_caps_meet_the_body() -> None:
    # Just inside and just outside the top end the values agree to first order.
    X = np.zeros((3, 1))
    Y = np.array([[4.5 - 1e-7], [4.5], [-6.0]])
    v = line_v(0.5, -4.5, 4.5, X, Y)
    assert v[0, 0] == pytest.approx(v[1, 0], rel=1e-9)


def test_gaussian_is_a_ridge_along_y() -> None:
    d = make_shape("gaussian", M)
    np.testing.assert_array_equal(d, np.broadcast_to(d[0], d.shape))
    assert d.max() == pytest.approx(0.5 / math.sqrt(2.0 * math.pi), rel=1e-12)
    assert int(np.argmax(d[0])) == index(0.0)


def test_oblique_lines_rotate_the_print_lines() -> None:
    x, y = grid(64)
    straight = make_shape("print_lines", 64)
    oblique = make_shape("oblique_lines", 64)
    assert np.abs(oblique - straight).max() > 0.02
    assert oblique.max() == pytest.approx(straight.max(), rel=0.05)
    np.testing.assert_allclose(oblique_lines(x, y, angle_deg=0.0), straight, rtol=1e-12, atol=1e-300)


def test_bump_peaks_at_its_center() -> None:
    d = make_shape("bump", M, center=[0.5, -0.25], sigma=0.1, height=0.07)
    assert d.max() == pytest.approx(0.07)
    assert np.unravel_index(np.argmax(d), d.shape) == (index(-0.25), index(0.5))


def test_flat_is_zero() -> None:
    assert not make_shape("flat", 8).any()


def test_unknown_shape_lists_the_known_ones() -> None:
    with pytest.raises(ValueError, match="unknown shape 'spiral'.*print_lines"):
        make_shape("spiral", 16)


@pytest.mark.parametrize("params, message", [
    ({"radius": 1.0}, "no parameter 'radius'.*sigma"),
    ({"sigma": 0.0}, "sigma=0.0 must be positive"),
    ({"height": -1.0}, "height=-1.0"),
    ({"center": [0.0]}, "center"),
])
def test_bump_rejects_bad_params(params: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        make_shape("bump", 16, **params)


@pytest.mark.parametrize("resolution", [1, 0, 2.5, True])
def test_bad_resolution(resolution: object) -> None:
    with pytest.raises(ValueError, match="resolution"):
        make_shape("flat", resolution)  # type: ignore[arg-type]


def test_letter_a_strokes_peak_at_their_height_and_fall_off_with_their_width() -> None:
    from framework.scene.printed_shapes import letter_a, segment_distance

    x, y = grid(257)
    d = letter_a(x, y)
    assert abs(float(d.max()) - 0.08) < 1e-3 and np.allclose(d, d[:, ::-1])  # mirror symmetric in x
    # On the left leg, half way down: the peak; one stroke width beside it: exp(-1/2) of it.
    apex, foot = (0.0, 0.7), (-0.504, -0.7)
    middle = np.array([[-0.252], [0.0]])
    assert float(letter_a(middle[0], middle[1])[0]) == pytest.approx(0.08)
    normal = np.array([1.4, -0.504]) / np.hypot(1.4, 0.504)  # perpendicular to the leg
    beside = middle[:, 0] + 0.05 * normal
    assert float(segment_distance(np.array([beside[0]]), np.array([beside[1]]), apex, foot)[0]) == pytest.approx(0.05)
    value = float(letter_a(np.array([beside[0]]), np.array([beside[1]]))[0])
    assert value == pytest.approx(0.08 * np.exp(-0.5), rel=1e-6)
    assert float(d[0, 0]) < 1e-12 and float(letter_a(np.array([0.0]), np.array([0.2]))[0]) < 1e-3  # inside the A
