"""Ray / height-field intersection: the bracketing planes and the hit search."""

from __future__ import annotations

import numpy as np

from operators.heightfield.catmull_rom import surface_gradient
from operators.heightfield.intersect_native import solve_hit, solve_hits
from operators.heightfield.surface import OVERSHOOT, HeightFieldGrid


def sampled_surface(d: np.ndarray, grid: HeightFieldGrid, samples: int) -> np.ndarray:
    xs = np.linspace(-grid.half_width, grid.half_width, samples)
    return np.array([[surface_gradient(d, x, y, -grid.half_width, grid.spacing)[0] for x in xs] for y in xs])


def test_bracketing_planes_hold_random_surfaces_and_are_reached_by_the_worst_patch():
    grid = HeightFieldGrid(base=0.1, half_width=1.0, resolution=9)
    rng = np.random.default_rng(3)
    for _ in range(5):
        d = rng.uniform(0.0, 0.05, (9, 9))
        zlo, zstart, zhi = grid.z_planes(d)
        s = grid.base + sampled_surface(d, grid, 161)
        assert zlo <= s.min() and s.max() <= zhi and zstart == grid.base + d.min()
    # Maximum where the Catmull-Rom weight products at a cell centre are positive, minimum where
    # negative: the surface there rises 9/32 of the range above the maximum, as far as zhi allows.
    sign = np.array([-1.0, 1.0, 1.0, -1.0])
    d = np.zeros((9, 9))
    d[2:6, 2:6] = (np.outer(sign, sign) > 0) * 0.04
    centre = -grid.half_width + 3.5 * grid.spacing
    peak = surface_gradient(d, centre, centre, -grid.half_width, grid.spacing)[0]
    assert np.isclose(peak, 0.04 + OVERSHOOT * 0.04, rtol=1e-12)
    assert np.isclose(grid.base + peak, grid.z_planes(d)[2], atol=2e-9)


def test_hit_is_the_first_root_of_the_gap_along_oblique_rays():
    grid = HeightFieldGrid(base=0.1, half_width=1.0, resolution=33)
    x = np.linspace(-1.0, 1.0, 33)
    # Two narrow ridges: oblique rays can graze one and must stop at the first crossing.
    d = 0.08 * (np.exp(-((x[None, :] - 0.1) / 0.06) ** 2) + np.exp(-((x[None, :] + 0.05) / 0.06) ** 2)
                ) * np.ones((33, 1))
    zlo, zstart, zhi = grid.z_planes(d)
    rng = np.random.default_rng(7)
    origin = np.array([-2.0, 0.0, 2.0])
    for _ in range(200):
        target = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.5, 0.5), grid.base])
        w = (target - origin) / np.linalg.norm(target - origin)
        t = solve_hit(d, grid.base, *origin, *w, -grid.half_width, grid.spacing, zlo, zstart, zhi,
                      *grid.slope_bounds(d))

        def gap(tt: float) -> float:
            p = origin + tt * w
            return p[2] - grid.base - surface_gradient(d, p[0], p[1], -grid.half_width, grid.spacing)[0]

        assert abs(gap(t)) < 1e-11
        before = np.linspace((zhi - origin[2]) / w[2], t, 400, endpoint=False)
        assert min(gap(tt) for tt in before) > 0.0


def test_slope_bounds_hold_on_random_surfaces():
    grid = HeightFieldGrid(base=0.1, half_width=1.0, resolution=9)
    rng = np.random.default_rng(5)
    xs = np.linspace(-grid.half_width, grid.half_width, 161)
    for _ in range(5):
        d = rng.uniform(0.0, 0.05, (9, 9))
        bound_x, bound_y = grid.slope_bounds(d)
        slopes = np.array([[surface_gradient(d, x, y, -grid.half_width, grid.spacing)[1:] for x in xs] for y in xs])
        steepest_x, steepest_y = np.abs(slopes).max(axis=(0, 1))
        assert steepest_x <= bound_x and steepest_y <= bound_y
        # Not so loose that rays which could skip the march are denied it.
        assert steepest_x > 0.3 * bound_x and steepest_y > 0.3 * bound_y


def test_skipping_the_march_on_monotone_rays_finds_the_same_hits():
    grid = HeightFieldGrid(base=0.1, half_width=1.0, resolution=33)
    x = np.linspace(-1.0, 1.0, 33)
    d = 0.05 * np.exp(-(x[None, :] ** 2 + x[:, None] ** 2) / 0.1)
    zlo, zstart, zhi = grid.z_planes(d)
    slope_x, slope_y = grid.slope_bounds(d)
    origin = np.array([0.0, 0.0, 10.0])
    rng = np.random.default_rng(11)
    for _ in range(300):
        target = np.array([rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), grid.base])
        w = (target - origin) / np.linalg.norm(target - origin)
        assert slope_x * abs(w[0]) + slope_y * abs(w[1]) < abs(w[2])  # the skip applies
        skipped = solve_hit(d, grid.base, *origin, *w, -grid.half_width, grid.spacing, zlo, zstart, zhi,
                            slope_x, slope_y)
        marched = solve_hit(d, grid.base, *origin, *w, -grid.half_width, grid.spacing, zlo, zstart, zhi,
                            np.inf, np.inf)
        assert abs(skipped - marched) <= 1e-12 * marched


def test_lockstep_search_of_a_packet_finds_the_hits_of_the_ray_by_ray_search():
    grid = HeightFieldGrid(base=0.1, half_width=1.0, resolution=33)
    x = np.linspace(-1.0, 1.0, 33)
    d = 0.05 * np.exp(-(x[None, :] ** 2 + x[:, None] ** 2) / 0.1) + 0.03 * np.exp(-((x[None, :] - 0.4) / 0.08) ** 2)
    zlo, zstart, zhi = grid.z_planes(d)
    slope_x, slope_y = grid.slope_bounds(d)
    # A light close to the surface: the flatter rays need the march, the steeper ones do not.
    origin = np.array([-0.3, 0.2, 0.6])
    rng = np.random.default_rng(13)
    count = 300
    targets = np.stack([rng.uniform(-1.0, 1.0, count), rng.uniform(-1.0, 1.0, count), np.full(count, grid.base)])
    dirs = (targets - origin[:, None]) / np.linalg.norm(targets - origin[:, None], axis=0)
    marching = slope_x * np.abs(dirs[0]) + slope_y * np.abs(dirs[1]) >= np.abs(dirs[2])
    assert 50 < marching.sum() < count - 50  # both kinds of ray in one packet
    t = np.empty(count)
    solve_hits(d, grid.base, *origin, dirs, count, -grid.half_width, grid.spacing, zlo, zstart, zhi, slope_x,
               slope_y, t, np.empty((5, count)))
    one_by_one = np.array([solve_hit(d, grid.base, *origin, *dirs[:, k], -grid.half_width, grid.spacing, zlo,
                                     zstart, zhi, slope_x, slope_y) for k in range(count)])
    assert np.abs(t - one_by_one).max() <= 1e-12 * one_by_one.max()
