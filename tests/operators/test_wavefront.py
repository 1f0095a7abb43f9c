"""The wavefront-triangle renderer (operators/wavefront) against independent truths: exact pixel
coverage, the analytic irradiance and power of a point light through a flat slab, the splat
renderer on a smooth lens, and bit-identical reruns."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.optimize import brentq

from operators.heightfield.operator import CausticOperator, OperatorSettings
from operators.scene import Light, Receiver, Scene, Substrate
from operators.wavefront.coverage import rasterize_grid, rasterize_triangles
from operators.wavefront.flux import ROW_BLOCK, grid_flux, grid_solid_angles, triangle_solid_angle
from operators.wavefront.renderer import WavefrontRenderer, wavefront_vertices
from tests.operators.conftest import bump

LIGHT_Z, H, S = 10.0, 0.1, -0.05  # the default scene's light height, substrate thickness, receiver plane


def _scene(
    resolution: int, half_width: float, wavelengths: tuple[float, ...] = (0.633,), walls: str = "clear"
) -> Scene:
    return Scene(light=Light(), substrate=Substrate(walls=walls), wavelengths=wavelengths,
                 receiver=Receiver(z=S, resolution=resolution, half_width=half_width))


def _triangle_area(t: np.ndarray) -> float:
    return 0.5 * abs((t[1, 0] - t[0, 0]) * (t[2, 1] - t[0, 1]) - (t[1, 1] - t[0, 1]) * (t[2, 0] - t[0, 0]))


def _supersampled_coverage(t: np.ndarray, n: int, per_pixel: int) -> np.ndarray:
    """Area of triangle t (3, 2) in every pixel of an n x n image by counting per_pixel^2 sample
    points (cell midpoints) per pixel inside it (half-plane tests)."""
    axis = (np.arange(n * per_pixel) + 0.5) / per_pixel
    y, x = np.meshgrid(axis, axis, indexing="ij")
    sides = [(t[(k + 1) % 3, 0] - t[k, 0]) * (y - t[k, 1]) - (t[(k + 1) % 3, 1] - t[k, 1]) * (x - t[k, 0])
             for k in range(3)]
    inside = ((sides[0] >= 0) & (sides[1] >= 0) & (sides[2] >= 0)) | (
        (sides[0] <= 0) & (sides[1] <= 0) & (sides[2] <= 0)
    )
    return inside.reshape(n, per_pixel, n, per_pixel).sum(axis=(1, 3)) / per_pixel ** 2


# -- 1. exact coverage --------------------------------------------------------------------------

def test_coverage_of_triangles_inside_the_image_sums_to_their_area():
    rng = np.random.default_rng(1)
    triangles = rng.uniform(0.0, 16.0, (500, 3, 2))
    areas = np.array([_triangle_area(t) for t in triangles])
    for t, area in zip(triangles[:50], areas[:50]):
        image = rasterize_triangles(t[None], np.array([area]), 16)
        assert image.min() >= 0.0
        assert abs(image.sum() - area) <= 1e-12 * max(area, 1.0)
    # Fluxes are spread per unit area: flux = area gives each triangle total = area, and all add.
    image = rasterize_triangles(triangles, np.ones(500), 16)
    assert abs(image.sum() - 500.0) < 1e-10


def test_coverage_of_triangles_partly_off_the_image_matches_supersampling():
    """Per pixel against 400^2 samples per pixel: a sample grid of spacing e misjudges at most the
    samples within e of an edge, so |error| <= perimeter * e (scaled by a margin of 1)."""
    rng = np.random.default_rng(2)
    per_pixel, n = 400, 4
    for _ in range(12):
        t = rng.uniform(-2.0, 6.0, (3, 2))
        area = _triangle_area(t)
        exact = rasterize_triangles(t[None], np.array([area]), n)  # flux = area: the image is the coverage
        sampled = _supersampled_coverage(t, n, per_pixel)
        perimeter = sum(math.dist(t[k], t[(k + 1) % 3]) for k in range(3))
        bound = perimeter / per_pixel
        assert np.abs(exact - sampled).max() <= bound, (t, np.abs(exact - sampled).max(), bound)
        assert abs(exact.sum() - sampled.sum()) <= bound
        assert exact.sum() <= area * (1 + 1e-12)


def test_half_pixel_and_triangle_inside_one_pixel():
    half = rasterize_triangles(np.array([[[1.0, 1.0], [2.0, 1.0], [2.0, 2.0]]]), np.array([3.0]), 4)
    expected = np.zeros((4, 4))
    expected[1, 1] = 3.0
    assert np.array_equal(half, expected)
    # The other half of pixel (row 2, col 0), and a half pixel split between two pixels' corners.
    other = rasterize_triangles(np.array([[[0.0, 2.0], [1.0, 3.0], [0.0, 3.0]]]), np.array([1.0]), 4)
    assert other[2, 0] == pytest.approx(1.0, abs=1e-15) and other.sum() == pytest.approx(1.0, abs=1e-15)
    split = rasterize_triangles(np.array([[[1.5, 0.0], [2.5, 0.0], [2.5, 1.0]]]), np.array([1.0]), 4)
    assert split[0, 1] == pytest.approx(0.25, abs=1e-15) and split[0, 2] == pytest.approx(0.75, abs=1e-15)
    inside = rasterize_triangles(np.array([[[2.1, 1.2], [2.8, 1.3], [2.5, 1.9]]]), np.array([0.7]), 4)
    assert inside[1, 2] == 0.7 and inside.sum() == 0.7
    # Degenerate (collinear): everything at the centroid's pixel; wholly off the image: lost.
    line = rasterize_triangles(np.array([[[0.5, 0.5], [1.5, 1.5], [2.5, 2.5]]]), np.array([2.0]), 4)
    assert line[1, 1] == 2.0 and line.sum() == 2.0
    assert rasterize_triangles(np.array([[[5.0, 0.0], [6.0, 0.0], [6.0, 1.0]]]), np.array([1.0]), 4).sum() == 0.0


def test_a_jittered_grid_with_flux_equal_to_area_paints_a_uniform_image():
    """Triangles that tile [0, n]^2 with flux = their area give irradiance 1 in every pixel,
    however their vertices are jittered (flipped ones excluded: jitter below half a step)."""
    rng = np.random.default_rng(3)
    k, n = 41, 8
    axis = np.linspace(0.0, n, k)
    y, x = np.meshgrid(axis, axis, indexing="ij")
    vertices = np.stack([x, y], axis=-1)
    step = n / (k - 1)
    vertices[1:-1, 1:-1] += rng.uniform(-0.3 * step, 0.3 * step, (k - 2, k - 2, 2))
    flux = np.empty((2, k - 1, k - 1))
    for i in range(k - 1):
        for j in range(k - 1):
            flux[0, i, j] = _triangle_area(vertices[[i, i, i + 1], [j, j + 1, j + 1]])
            flux[1, i, j] = _triangle_area(vertices[[i, i + 1, i + 1], [j, j + 1, j]])
    image = rasterize_grid(vertices, flux, n)
    assert np.abs(image - 1.0).max() < 1e-12


# -- 2. flat slab: analytic irradiance ----------------------------------------------------------

def _slab_map(rho: np.ndarray, n: float) -> np.ndarray:
    """Receiver radius of the ray aimed at radius rho on the top (z = h): straight to the top,
    h tan(theta_g) in the glass (sin theta_g = sin theta / n), |s| tan(theta) below (parallel to
    the incoming ray)."""
    d = LIGHT_Z - H
    sin = rho / np.sqrt(rho ** 2 + d ** 2)
    return rho * (1.0 + abs(S) / d) + H * sin / np.sqrt(n * n - sin * sin)


def _slab_map_derivative(rho: np.ndarray, n: float) -> np.ndarray:
    d = LIGHT_Z - H
    sin = rho / np.sqrt(rho ** 2 + d ** 2)
    return 1.0 + abs(S) / d + H * n * n * d * d / ((n * n - sin * sin) ** 1.5 * (rho ** 2 + d ** 2) ** 1.5)


def _slab_aim_radius(radius: np.ndarray, n: float) -> np.ndarray:
    """Inverse of the slab map by Newton's method from its paraxial slope."""
    d = LIGHT_Z - H
    rho = radius / (1.0 + abs(S) / d + H / (n * d))
    for _ in range(30):
        rho = rho - (_slab_map(rho, n) - radius) / _slab_map_derivative(rho, n)
    return rho


def _slab_irradiance(x: np.ndarray, y: np.ndarray, n: float) -> np.ndarray:
    """E = (P / 4 pi) (l_z - h) / r^3 (flux per unit aim area) over the radial map's Jacobian
    (R / rho) dR/drho, P = 1."""
    radius = np.hypot(x, y)
    rho = _slab_aim_radius(radius, n)
    d = LIGHT_Z - H
    density = d / (rho ** 2 + d ** 2) ** 1.5 / (4.0 * math.pi)
    return density / (radius / rho * _slab_map_derivative(rho, n))


def _pixel_means(f, scene: Scene, order: int = 4) -> np.ndarray:
    """Mean of f(x, y) over every receiver pixel, [row = y, col = x], by Gauss-Legendre (order^2)."""
    px, n, half = scene.receiver.pixel_size, scene.receiver.resolution, scene.receiver.half_width
    nodes, weights = np.polynomial.legendre.leggauss(order)
    corners = -half + px * np.arange(n)
    points = corners[:, None] + 0.5 * px * (nodes[None, :] + 1.0)  # (n, order)
    y, x = points.reshape(-1)[:, None], points.reshape(-1)[None, :]
    values = f(np.broadcast_to(x, (y.size, x.size)), np.broadcast_to(y, (y.size, x.size))).reshape(n, order, n, order)
    w = 0.25 * weights[None, :, None, None] * weights[None, None, None, :]
    return (values * w).sum(axis=(1, 3))


def test_slab_map_derivative_is_that_of_the_map():
    rho = np.linspace(0.01, 1.0, 50)
    e = 1e-6
    numeric = (_slab_map(rho + e, 1.457) - _slab_map(rho - e, 1.457)) / (2 * e)
    assert np.abs(numeric / _slab_map_derivative(rho, 1.457) - 1.0).max() < 1e-9


def test_flat_slab_matches_the_analytic_irradiance():
    """Pixel means of the analytic irradiance (4 x 4 Gauss points per pixel). Measured max relative
    error: 5.7e-6 at K = 257, 8.1e-7 at K = 513 (10.7 vertices per pixel side), 3.0e-8 at K = 1025."""
    scene = _scene(48, 0.9)
    renderer = WavefrontRenderer(scene, vertices=513)
    image = renderer.render(torch.zeros(32, 32, dtype=torch.float64))
    assert image.shape == (1, 48, 48) and image.dtype == torch.float64
    expected = _pixel_means(lambda x, y: _slab_irradiance(x, y, scene.indices[0]), scene)
    error = np.abs(image[0].numpy() / expected - 1.0)
    assert error.max() < 5e-6, error.max()


def _fresnel_unpolarised(cos_i: np.ndarray, eta: float) -> np.ndarray:
    """Transmittance 1 - (R_s + R_p) / 2 from a medium into one with relative index 1 / eta."""
    sin_t = eta * np.sqrt(1.0 - cos_i ** 2)
    cos_t = np.sqrt(1.0 - sin_t ** 2)
    rs = ((eta * cos_i - cos_t) / (eta * cos_i + cos_t)) ** 2
    rp = ((eta * cos_t - cos_i) / (eta * cos_t + cos_i)) ** 2
    return 1.0 - 0.5 * (rs + rp)


def test_fresnel_weights_match_the_analytic_transmittance():
    scene = _scene(16, 0.9)
    n = scene.indices[0]
    zero = torch.zeros(32, 32, dtype=torch.float64)
    ratio = (WavefrontRenderer(scene, vertices=257, fresnel=True).render(zero)
             / WavefrontRenderer(scene, vertices=257).render(zero))[0].numpy()

    def transmittance(x, y):
        rho = _slab_aim_radius(np.hypot(x, y), n)
        cos_i = (LIGHT_Z - H) / np.hypot(rho, LIGHT_Z - H)
        cos_g = np.sqrt(1.0 - (1.0 - cos_i ** 2) / n ** 2)
        return _fresnel_unpolarised(cos_i, 1.0 / n) * _fresnel_unpolarised(cos_g, n)

    # The pixel mean of E T over that of E; T varies by 1e-4 over the receiver, so the plain
    # pixel mean of T agrees to far below the tolerance (measured: 8.4e-10).
    expected = _pixel_means(transmittance, scene)
    assert np.abs(ratio / expected - 1.0).max() < 1e-7


# -- 3. energy -----------------------------------------------------------------------------------

def _solid_angle_of_square(half: float, distance: float) -> float:
    return 4.0 * math.atan(half * half / (distance * math.sqrt(2.0 * half * half + distance ** 2)))


def _solid_angle_within(rho_max, half: float, distance: float, order: int = 64) -> float:
    """Solid angle of the region {rho <= rho_max(phi)} of a plane ``distance`` below the light
    with the square's 8-fold symmetry: 8 int_0^{pi/4} (1 - distance / sqrt(rho_max^2 + distance^2)) dphi."""
    nodes, weights = np.polynomial.legendre.leggauss(order)
    phi = (nodes + 1.0) * math.pi / 8.0
    rho = np.array([rho_max(p) for p in phi])
    return float(8.0 * np.sum(weights * math.pi / 8.0 * (1.0 - distance / np.sqrt(rho ** 2 + distance ** 2))))


def test_energy_of_a_flat_slab_on_a_large_receiver():
    """All light through the top square is either on the image or in dropped triangles
    (P / 4 pi times the square's closed-form solid angle, to rounding). With absorbing walls what
    reaches the receiver is the light that leaves through the bottom, not the side walls: the aim points q
    with |q_x| s, |q_y| s <= W, s = 1 + h / sqrt(n^2 (|q|^2 + d^2) - |q|^2) the slab's radial
    stretch; the drop loses at most the lit part of strips Delta / 2^L wide along the edge,
    relative 2 Delta / (W 2^L). Measured (K = 257, Delta = W / 128): -1.9e-3 with L = 0, -9.2e-4
    with L = 4, -1.9e-4 with L = 6; the analytic bound at L = 6 is 2.4e-4. With clear walls the
    whole square's light lands, less the triangles cut where the light starts to meet a wall
    (one line per wall: the same bound)."""
    scene = _scene(64, 1.3, walls="absorbing")
    n, d, half = scene.indices[0], LIGHT_Z - H, 1.0
    square = _solid_angle_of_square(half, d) / (4.0 * math.pi)
    assert _solid_angle_within(lambda p: half / math.cos(p), half, d) / (4.0 * math.pi) == pytest.approx(
        square, rel=1e-13
    )

    def stretch(rho):
        return 1.0 + H / math.sqrt(n * n * (rho * rho + d * d) - rho * rho)

    transmitted = _solid_angle_within(lambda p: brentq(lambda r: r * math.cos(p) * stretch(r) - half, 0.0, 2.0,
                                                        xtol=1e-15), half, d) / (4.0 * math.pi)
    errors = []
    k = 257
    for levels in (0, 4, 6):
        renderer = WavefrontRenderer(scene, vertices=k, subdivisions=levels)
        image = renderer.render(torch.zeros(16, 16, dtype=torch.float64))
        budget = renderer.last_budget
        received = float(image.sum()) * renderer.pixel_area
        assert received == pytest.approx(budget.received, rel=1e-12)
        assert budget.emitted == pytest.approx(square, rel=1e-12)
        assert budget.received + budget.dropped == pytest.approx(square, rel=1e-12)  # nothing falls off
        errors.append(received / transmitted - 1.0)
        assert -2.0 * (2.0 / (k - 1)) / half / 2 ** levels <= errors[-1] <= 1e-12, (levels, errors[-1])
    assert errors[0] < errors[1] < errors[2], errors
    clear = []
    for levels in (0, 6):
        renderer = WavefrontRenderer(_scene(64, 1.3), vertices=k, subdivisions=levels)
        received = float(renderer.render(torch.zeros(16, 16, dtype=torch.float64)).sum()) * renderer.pixel_area
        assert received + renderer.last_budget.dropped == pytest.approx(square, rel=1e-12)
        clear.append(received / square - 1.0)
        assert -2.0 * (2.0 / (k - 1)) / half / 2 ** levels <= clear[-1] <= 1e-12, (levels, clear[-1])
    assert clear[0] < clear[1], clear


# -- 4. a smooth lens against the splat renderer --------------------------------------------------

def test_a_focusing_bump_matches_the_splat_renderer():
    """A Gaussian bump (height 0.1, sigma 0.25: a lens of focal length ~1.4 at its top) against
    CausticOperator with 2^24 photons, footprints of 0.5 px and a 0.3 px filter (64 px). The
    difference is the splat's own blur (footprints, filter, the pixel box modelled by a wider
    footprint): measured relative L2 6.75e-3 with 2^22, 2^24 and 2^26 photons alike (so not
    photon noise), while the wavefront render at K = 1025 is within 4e-6 of K = 2049. Compared
    inside |x|, |y| < 0.95: the light the side walls reflect lands within 0.4 pixels of the
    receiver's edge, where the splat's footprints spill off the image."""
    scene = _scene(64, 1.0)
    heights = bump(64, sigma=0.25, height=0.1)
    exact = WavefrontRenderer(scene, vertices=1025).render(heights)
    splat = CausticOperator(scene, OperatorSettings(photons=2 ** 24, footprint_px=0.5, min_footprint_px=0.3,
                                                    pixel_integration=True, dtype="float64")).render(heights)
    peak = float(exact.max()) / float(exact[0, :4, :4].mean())
    assert peak > 1.2  # it focuses
    inside = (slice(None), slice(2, -2), slice(2, -2))
    difference = float(torch.linalg.vector_norm((exact - splat)[inside]) / torch.linalg.vector_norm(exact[inside]))
    assert difference < 1e-2, difference


# -- 5. reruns, channels, settings ------------------------------------------------------------------

def test_reruns_are_bit_identical_and_channels_split_the_power():
    heights = bump(32, sigma=0.3, height=0.05)
    both = WavefrontRenderer(_scene(24, 1.0, (0.45, 0.7)), vertices=129)
    first = both.render(heights)
    assert torch.equal(first, both.render(heights))
    assert torch.equal(first, WavefrontRenderer(_scene(24, 1.0, (0.45, 0.7)), vertices=129).render(heights))
    for k, wavelength in enumerate((0.45, 0.7)):
        alone = WavefrontRenderer(_scene(24, 1.0, (wavelength,)), vertices=129).render(heights)[0]
        assert torch.allclose(first[k], 0.5 * alone, rtol=1e-13, atol=0.0)
    assert not torch.allclose(first[0], first[1], rtol=1e-4)  # dispersion moves the caustic


def test_native_and_torch_tracers_agree():
    """The two tracers (fused-kernel optics and trace_substrate) give the same image to rounding,
    with Fresnel weights and lost rays (side walls) on a bump."""
    scene = _scene(24, 1.05)
    heights = bump(32, sigma=0.3, height=0.05)
    native = WavefrontRenderer(scene, vertices=129, fresnel=True).render(heights)
    reference = WavefrontRenderer(scene, vertices=129, fresnel=True, tracer="torch").render(heights)
    assert float((native - reference).abs().max() / reference.max()) < 1e-11


def test_default_grid_and_settings():
    scene = _scene(128, 1.0)
    renderer = WavefrontRenderer(scene)
    assert renderer.describe()["vertices_per_pixel"] >= 8.0
    assert renderer.vertices == 1041  # 8 * 128 * (l_z - s) / (l_z - h) = 1039.5, rounded up, + 1
    assert wavefront_vertices(4 * 2 ** 20, 1) == 2049 and wavefront_vertices(2 * 4 * 2 ** 20, 2) == 2049
    with pytest.raises(ValueError, match="vertices"):
        WavefrontRenderer(scene, vertices=1)
    with pytest.raises(ValueError, match="tracer"):
        WavefrontRenderer(scene, vertices=9, tracer="cuda")
    with pytest.raises(ValueError, match="subdivisions"):
        WavefrontRenderer(scene, vertices=9, subdivisions=-1)
    with pytest.raises(ValueError, match="NaN"):
        WavefrontRenderer(scene, vertices=9).render(torch.full((8, 8), float("nan")))


@pytest.mark.parametrize("k", [5, ROW_BLOCK, ROW_BLOCK + 1, ROW_BLOCK + 2, 3 * ROW_BLOCK - 7])
def test_the_grids_solid_angles_and_fluxes_by_row_blocks_equal_the_whole_grid_formulas(k):
    """grid_solid_angles and grid_flux work ROW_BLOCK rows at a time: the same bits as the formulas
    over the whole grid at once, for grids around the block size."""
    light = (0.1, -0.2, 10.0)
    axis = -1.0 + 2.0 * np.arange(k) / (k - 1)
    x, y = (axis - light[0])[None, :], (axis - light[1])[:, None]
    x0, x1, y0, y1 = x[:, :-1], x[:, 1:], y[:-1], y[1:]
    dz = 0.1 - light[2]
    omega = np.stack(
        [triangle_solid_angle(x0, y0, x1, y0, x1, y1, dz), triangle_solid_angle(x0, y0, x1, y1, x0, y1, dz)]
    )
    assert np.array_equal(grid_solid_angles(k, 1.0, 0.1, light), omega)
    rng = np.random.default_rng(k)
    path = np.where(rng.random((k, k)) < 0.1, 0.0, np.where(rng.random((k, k)) < 0.05, 2.0, 1.0))
    ratio = np.where(path == 0.0, 0.0, rng.random((k, k)))
    r00, r11, third = ratio[:-1, :-1], ratio[1:, 1:], np.stack([ratio[:-1, 1:], ratio[1:, :-1]])
    c00, c11, c3 = path[:-1, :-1], path[1:, 1:], np.stack([path[:-1, 1:], path[1:, :-1]])
    one_path = (c00 == c11) & (c00 == c3)
    flux, mixed = grid_flux(omega, ratio, path, 0.7)
    assert np.array_equal(flux, np.where(one_path & (c00 != 0.0), 0.7 * omega * (r00 + r11 + third) / 3.0, 0.0))
    assert np.array_equal(mixed, ~one_path)
