"""The default irradiance model against the optics of a plano-convex paraboloid lens printed on
the substrate: where it focuses, how much light its focal spot holds, and where an off-axis lens
puts its spot.

The print is the cap d(x, y) = max(0, c - rho^2 / (2 R)), rho the distance from the lens centre,
R = 0.5, aperture radius a = 0.3 (so c = a^2 / (2 R) = 0.09; rim slope a / R = 0.6), sampled on
m = 512 heights over the default substrate (h = 0.1, W = 1) and lit by the default light: P = 1 W
at (0, 0, 10). The glass is fused silica at 0.633 um (n = 1.45701). The operator is built as
conf/operator/height_field.yaml builds it (cell footprints, 0.1-pixel filter, 4 x supersampled,
pixel integration), in float64.

Two facts of the sampled surface matter below.

- Catmull-Rom interpolation reproduces quadratics exactly, and the cap is a quadratic wherever
  all 4 x 4 samples of a cell's stencil lie inside the rim, i.e. for rho < a - 2 sqrt(2) D
  (D = 2 W / (m - 1) the sample spacing); beyond rho = a + 2 sqrt(2) D it is flat. There the
  renderer's tracer follows the analytic lens exactly (test 0: the same rays to 1e-14). Only the
  rim band between is the interpolant's own: a rounded kink whose slope runs from the lens's
  down to the flat glass's.
- A ray that the lens bends by a fraction phi of the full deflection lands, near focus, at about
  (1 - phi) S from the spot, S the radius of the aperture's straight-through shadow: the rim
  band spreads a faint halo over the whole shadow disk (3.4% of the lens's flux lands beyond
  0.03 of the spot at m = 256, 1.6% at m = 512; its irradiance at S / 2 is 1.6e-5 at m = 512,
  against 6.6e-4 of the flat glass outside S).

The exact ray optics of the analytic lens used as the reference (:func:`_trace_lens`) are
closed-form: the ray meets the paraboloid at a root of a quadratic, refracts by Snell's law in
vector form, and crosses the flat bottom.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from operators.heightfield.operator import CausticOperator
from operators.scene import Scene
from operators.wavefront.renderer import WavefrontRenderer

R_CURV = 0.5  # radius of curvature at the paraboloid's vertex (scene units)
APERTURE = 0.3  # radius a of the circle where the cap meets the flat glass
CAP = APERTURE ** 2 / (2.0 * R_CURV)  # c, the cap's height above the top plane z = h
M = 512  # height samples per side
PHOTONS = 2_000_000
SCAN_RESOLUTION, SCAN_HALF_WIDTH = 128, 0.2  # pixel 3.1e-3: the best-focus spot (rms 3.4e-3) spans ~2 pixels
WINDOW = 0.03  # radius of the region in which the spot's second moment is taken (scene units)
OFF_AXIS = (0.3, -0.2)

SCENE = Scene()  # the default light, substrate and glass
LX, LY, LZ = SCENE.light.position
H = SCENE.substrate.thickness
N_GLASS = SCENE.indices[0]
SPACING = 2.0 * SCENE.substrate.half_width / (M - 1)


def _cap(centre: tuple[float, float] = (0.0, 0.0)) -> torch.Tensor:
    """Heights (M, M), d[row, col] at x = -W + col 2 W / (M - 1) (y likewise by row)."""
    axis = np.linspace(-SCENE.substrate.half_width, SCENE.substrate.half_width, M)
    y, x = np.meshgrid(axis, axis, indexing="ij")
    return torch.from_numpy(np.maximum(0.0, CAP - ((x - centre[0]) ** 2 + (y - centre[1]) ** 2) / (2.0 * R_CURV)))


def _render(heights: torch.Tensor, z: float, resolution: int, half_width: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The default model's irradiance (n, n) on the receiver plane z, the pixel centres' x and y
    (n, n) and the pixel area."""
    receiver = dataclasses.replace(SCENE.receiver, z=z, resolution=resolution, half_width=half_width)
    scene = dataclasses.replace(SCENE, receiver=receiver)
    op = CausticOperator.from_config(scene, PHOTONS, 0, footprint_px="cell", min_footprint_px=0.1, supersample=4,
                                     pixel_integration=True, max_pixel_radius=20, dtype="float64")
    image = op.render(heights)[0].numpy()
    centres = np.array(receiver.pixel_centres())
    y, x = np.meshgrid(centres, centres, indexing="ij")
    return image, x, y, receiver.pixel_size ** 2


# -- closed-form optics ---------------------------------------------------------------------------

def _paraxial_focus() -> tuple[float, float]:
    """Paraxial image of the light: its height z_p and its distance below the lens vertex.

    The vertex (z = t, t = h + c) is the lens's first principal plane; its surface power is
    (n - 1) / R. With the object u = l_z - t above, n / v' = (n - 1) / R - 1 / u puts the image
    v' = n v below the vertex inside glass, 1 / v = 1 / f - 1 / u, f = R / (n - 1) (the thin-lens
    image in glass-free terms). The flat bottom, t below the vertex, refracts the converging cone
    back into air: the image appears (v' - t) / n below it, z_p = -(v - t / n), i.e. the glass-free
    image v below the vertex moved down by the slab's t (1 - 1 / n).
    Here f = 1.0941, u = 9.81, v = 1.2314, z_p = -1.1010, 1.2910 below the vertex."""
    t = H + CAP
    f = R_CURV / (N_GLASS - 1.0)
    v = 1.0 / (1.0 / f - 1.0 / (LZ - t))
    z_p = -(v - t / N_GLASS)
    return z_p, t - z_p


def _aperture_rays(centre: tuple[float, float], radius: float, per_side: int = 601
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Aim points (N, 2) on the plane z = h inside the disk of ``radius`` around ``centre`` (a
    square grid) and their flux weights, the light's cos(theta) / r^2 per unit aim area. The rays
    that meet the cap are exactly those aimed inside the rim circle, which lies on z = h."""
    g = np.linspace(-radius, radius, per_side)
    x, y = np.meshgrid(g, g)
    inside = x ** 2 + y ** 2 < radius ** 2
    aim = np.stack([x[inside] + centre[0], y[inside] + centre[1]], axis=1)
    dist2 = (aim[:, 0] - LX) ** 2 + (aim[:, 1] - LY) ** 2 + (LZ - H) ** 2
    return aim, (LZ - H) / dist2 ** 1.5


def _trace_lens(aim: np.ndarray, centre: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Exact rays from the light aimed at ``aim`` (on z = h) through the analytic cap centred at
    ``centre`` and the substrate: each leaves the bottom at b (N, 2) with lateral slope s (N, 2)
    (d(x, y) / dz), so it crosses the plane z < 0 at b + z s."""
    light = np.array([LX, LY, LZ])
    w = np.column_stack([aim, np.full(len(aim), H)]) - light
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    # light + t w on z = h + c - |xy - centre|^2 / (2 R): q2 t^2 + q1 t + q0 = 0, first root.
    ox, oy = LX - centre[0], LY - centre[1]
    q2 = (w[:, 0] ** 2 + w[:, 1] ** 2) / (2.0 * R_CURV)
    q1 = w[:, 2] + (ox * w[:, 0] + oy * w[:, 1]) / R_CURV
    q0 = LZ - H - CAP + (ox * ox + oy * oy) / (2.0 * R_CURV)
    t = 2.0 * q0 / (-q1 + np.sqrt(q1 * q1 - 4.0 * q2 * q0))
    p = light + t[:, None] * w
    normal = np.column_stack([(p[:, 0] - centre[0]) / R_CURV, (p[:, 1] - centre[1]) / R_CURV, np.ones(len(p))])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    eta = 1.0 / N_GLASS
    cos_i = -(w * normal).sum(axis=1)
    cos_t = np.sqrt(1.0 - eta ** 2 * (1.0 - cos_i ** 2))
    inner = eta * w + (eta * cos_i - cos_t)[:, None] * normal
    bottom = p[:, :2] - (p[:, 2] / inner[:, 2])[:, None] * inner[:, :2]
    lateral = N_GLASS * inner[:, :2]  # Snell at the flat bottom keeps n sin(theta) and the azimuth
    return bottom, lateral / -np.sqrt(1.0 - (lateral ** 2).sum(axis=1))[:, None]


def _best_focus(aperture: float) -> float:
    """Plane of the smallest flux-weighted RMS spot radius of the exact rays through the part
    rho < ``aperture`` of the analytic cap (on axis). A ray crosses z at b + z s, so the spot's
    second moment about its centroid is a quadratic in z with its minimum at
    z* = -<b's'> / <s'^2> (primes: minus the flux-weighted means)."""
    aim, weight = _aperture_rays((0.0, 0.0), aperture)
    b, s = _trace_lens(aim, (0.0, 0.0))
    b = b - np.average(b, axis=0, weights=weight)
    s = s - np.average(s, axis=0, weights=weight)
    return -float(np.sum(weight * (b * s).sum(axis=1)) / np.sum(weight * (s * s).sum(axis=1)))


def _marginal_focus() -> float:
    """Where the marginal ray (aimed at the rim, rho -> a) crosses the axis."""
    b, s = _trace_lens(np.array([[APERTURE * (1.0 - 1e-9), 0.0]]), (0.0, 0.0))
    return -float(b[0, 0] / s[0, 0])


def _straight_through(aim_radius: float, z: float) -> float:
    """Radius on the plane z at which a ray aimed at radius ``aim_radius`` on z = h lands through
    flat glass: a + h tan(theta_g) + |z| tan(theta), tan(theta) = a / (l_z - h), n sin(theta_g) = sin(theta)."""
    tan_air = aim_radius / (LZ - H)
    sin_glass = tan_air / math.hypot(1.0, tan_air) / N_GLASS
    return aim_radius + H * sin_glass / math.sqrt(1.0 - sin_glass ** 2) + abs(z) * tan_air


# -- the renders --------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def focus_scan() -> dict:
    """The on-axis lens rendered on five receiver planes from the paraxial focus z_p to 8% of the
    focal distance beyond it (spherical aberration moves the best focus away from the lens)."""
    z_p, distance = _paraxial_focus()
    heights = _cap()
    planes = [z_p - k * 0.02 * distance for k in range(5)]
    return {"z": np.array(planes), "renders": [_render(heights, z, SCAN_RESOLUTION, SCAN_HALF_WIDTH) for z in planes]}


def _second_moment(image: np.ndarray, x: np.ndarray, y: np.ndarray, centre: tuple[float, float],
                   radius: float) -> float:
    """Second moment of the irradiance about its centroid within ``radius`` of ``centre``."""
    inside = np.hypot(x - centre[0], y - centre[1]) < radius
    e, px, py = image[inside], x[inside], y[inside]
    cx, cy = np.average(px, weights=e), np.average(py, weights=e)
    return float(np.average((px - cx) ** 2 + (py - cy) ** 2, weights=e))


# -- 0. the traced surface ----------------------------------------------------------------------

@pytest.mark.parametrize("centre", [(0.0, 0.0), OFF_AXIS])
def test_tracer_follows_the_analytic_lens_inside_the_rim_band(centre):
    """Where the Catmull-Rom stencil lies inside the rim (rho < a - 2 sqrt(2) D) the surface the
    renderer traces is the paraboloid itself (quadratic precision), so its rays (the project's
    native tracer, through :meth:`WavefrontRenderer.trace`) land where the exact rays of
    :func:`_trace_lens` do. Measured: 2e-14 apart; asserted 1e-10 (scene units)."""
    z = -1.15
    receiver = dataclasses.replace(SCENE.receiver, z=z, resolution=64, half_width=1.0)
    scene = dataclasses.replace(SCENE, receiver=receiver)
    aim, _ = _aperture_rays(centre, APERTURE - 2.0 * math.sqrt(2.0) * SPACING, per_side=41)
    corners, transmitted, _ = WavefrontRenderer(scene, vertices=3).trace(_cap(centre), aim, 0)
    landed = corners * receiver.pixel_size - receiver.half_width  # pixel-corner units -> scene units
    b, s = _trace_lens(aim, centre)
    assert np.all(transmitted == 1.0)
    assert np.abs(landed - (b + z * s)).max() < 1e-10


# -- 1. focus -------------------------------------------------------------------------------------

def test_best_focus_lies_at_the_aberrated_paraxial_focus(focus_scan):
    """The plane of the smallest RMS spot of the render against the paraxial focus and against
    the exact best focus of the analytic lens.

    Measured: the render's second moment within WINDOW = 0.03 of the axis on each of the five
    planes, and the vertex of the parabola through them (geometric rays cross the planes along
    straight lines, so the moment of all the spot's light is exactly quadratic in z; the pixel
    box and filter add a constant). WINDOW holds the whole geometric spot on every plane
    (asserted) and lies far inside the shadow of the aperture (radius S ~ 0.34), where no light
    through the flat glass lands.

    Paraxial focus z_p = -1.1010 (:func:`_paraxial_focus`). Spherical aberration: the paraboloid
    (conic -1, stronger than the aplanatic -1 / n^2 for a far source) and the slab in the
    converging beam both push the marginal rays past the paraxial focus, to -1.1846
    (:func:`_marginal_focus`): 6.5% of the focal distance. For third-order aberration the
    transverse error is A r^3 + B r (B the defocus) and the RMS over the pupil is least at
    B = -2 A / 3, two thirds of the way from the paraxial to the marginal focus: -1.1567; the
    exact rays' best RMS plane (:func:`_best_focus`) is -1.1569 (ratio 0.667, asserted 2/3 within
    1%). So the best focus lies 4.3% of the focal distance beyond z_p; asserted: within 5% of it
    and beyond it.

    The sampled surface's rim band (see the module docstring) bends its rays only partly and
    acts as a soft edge of the aperture: the exact rays give the bracket
    [best focus through rho < a, best focus through rho < a - 2 sqrt(2) D] = [-1.1569, -1.1529]
    (0.3% of the focal distance wide; with the same measurement over seven planes the render's
    best focus is -1.1526 at m = 256, -1.1550 at m = 512 and -1.1560 at m = 1024, converging on
    -1.1569 linearly in D). The render must lie in it, to within 0.05% of the focal distance for
    the fit and the photon pattern (seeds 0 and 1 differ by 6e-6). Measured: -1.1548, 0.16% of
    the focal distance short of the analytic lens's best focus and 4.2% beyond z_p."""
    z_p, distance = _paraxial_focus()
    z_best = _best_focus(APERTURE)
    z_marginal = _marginal_focus()
    assert abs((z_best - z_p) / (z_marginal - z_p) - 2.0 / 3.0) < 0.01 * 2.0 / 3.0, (z_p, z_best, z_marginal)
    z_soft = _best_focus(APERTURE - 2.0 * math.sqrt(2.0) * SPACING)

    aim, _ = _aperture_rays((0.0, 0.0), APERTURE)
    b, s = _trace_lens(aim, (0.0, 0.0))
    for z in focus_scan["z"]:
        assert np.hypot(*(b + z * s).T).max() < WINDOW  # the whole geometric spot is in the window

    moments = [_second_moment(image, x, y, (0.0, 0.0), WINDOW) for image, x, y, _ in focus_scan["renders"]]
    quadratic = np.polyfit(focus_scan["z"], moments, 2)
    z_render = -quadratic[1] / (2.0 * quadratic[0])
    margin = 5e-4 * distance
    assert z_best - margin < z_render < z_soft + margin, (z_render, z_best, z_soft)
    assert z_render < z_p and abs(z_render - z_p) < 0.05 * distance, (z_render, z_p, distance)
    # the best focus is a minimum: the spot grows on both sides (RMS 3.4e-3 at best, ~1e-2 at z_p)
    assert quadratic[0] > 0.0 and min(moments) < 0.5 * moments[0]


# -- 2. energy ------------------------------------------------------------------------------------

def test_focal_spot_holds_the_flux_incident_on_the_aperture(focus_scan):
    """The flux within S / 2 of the axis on the plane nearest the best focus equals the flux
    that falls on the aperture, P / (4 pi) Omega, Omega = 2 pi (1 - cos theta) the solid angle of
    the rim disk (on z = h) from the light, cos theta = u / sqrt(u^2 + a^2), u = l_z - h:
    2.2941e-4 W.

    The region. S = 0.337 is the radius of the aperture's straight-through shadow on that plane
    (:func:`_straight_through`): light through the flat glass lands outside it, so the flat
    glass adds nothing to the region and nothing needs subtracting. The lens's rays land within
    the spot (rms 3.4e-3, all within 0.03) far inside S / 2. The rim band's rays, bent by a
    fraction phi of the lens's deflection, land at about (1 - phi) S: those counted are the ones
    with phi > 1/2. The interpolant rounds the kink symmetrically about the rim (Catmull-Rom is
    a symmetric kernel with linear precision; the rim circle meets the sample grid at every
    phase, which averages it into a convolution with that kernel), so the rays that it bends by
    more than half outside the rim balance those it bends by less than half inside, and the
    count through the band is the flux through the band's inner half to first order in D / a.
    The band (|rho - a| < 2 sqrt(2) D) carries 2 * 2 sqrt(2) D / a = 7% of the lens's flux, so
    the second-order remainder is ~(2 sqrt(2) D / a)^2 = 0.14%; the photon pattern's quadrature
    error of the flux through a disk is ~1e-4 (R2 points, 141,000 on the aperture; seeds 0 and 1
    differ by 5e-5); pixels
    straddling the region's edge there cut through the halo alone (irradiance 1.6e-5 against
    the spot's ~0.5). Tolerance 0.5%. Measured: 0.99958 of the aperture's flux (seed 1:
    0.99963; 0.99992 at m = 256, 0.99995 at m = 1024); counting within 0.4 S or 0.6 S instead
    changes it by -0.25% / +0.25%: the halo. The spot proper (within 0.03) holds 98.4%."""
    index = int(np.argmin(np.abs(focus_scan["z"] - _best_focus(APERTURE))))
    z = float(focus_scan["z"][index])
    image, x, y, pixel_area = focus_scan["renders"][index]
    shadow = _straight_through(APERTURE, z)
    assert shadow / 2.0 + 2.0 * math.sqrt(pixel_area) < SCAN_HALF_WIDTH  # the region lies on the receiver
    spot_flux = float(image[np.hypot(x, y) < shadow / 2.0].sum()) * pixel_area
    u = LZ - H
    omega = 2.0 * math.pi * (1.0 - u / math.hypot(u, APERTURE))
    expected = SCENE.light.power / (4.0 * math.pi) * omega
    assert abs(spot_flux / expected - 1.0) < 5e-3, (spot_flux, expected)


# -- 3. off axis ----------------------------------------------------------------------------------

def test_off_axis_spot_centroid_lies_on_the_chief_ray():
    """The lens centred at (0.3, -0.2): its spot's centroid against the landing point of the
    chief ray through the lens's vertex (the nodal ray).

    The ray from the light to the vertex meets the cap where its normal is vertical, so it
    refracts as at flat glass and crosses glass of thickness t = h + c to the flat bottom:
    through the slab it keeps its direction and shifts sideways. In thin-lens terms: undeviated
    through the lens's centre, displaced by the slab. With r_v = |(x0, y0)| = 0.3606 and
    tan(theta) = r_v / (l_z - t), n sin(theta_g) = sin(theta), it lands on the plane z at radius
    r_v + t tan(theta_g) + |z| tan(theta) along (x0, y0), here (0.33937, -0.22624) on the best
    focus plane z = -1.1569 (paraxially the spot sits exactly there: the vertex is the lens's
    first nodal point).

    Off axis by 2.1 degrees the lens has coma, whose flare is one-sided: the exact rays' centroid
    (:func:`_trace_lens` over the aperture, flux-weighted) lies 1.4e-3 from the chief ray, toward
    the axis: 0.36 pixels of the 256-pixel receiver over [-0.5, 0.5]^2 (pixel 3.9e-3; the spot's
    rms is 0.9 pixel in the exact rays, 1.1 rendered). Asserted: the render's centroid (within
    0.03 of the chief ray's landing, inside the aperture's shadow) is within 0.5 pixel of the
    chief ray, and, tighter, within 0.1 pixel of the exact rays' centroid (room for the pixel
    quadrature of a 1-pixel spot and for the rim band's halo, which is not centred on the spot off
    axis; on a 128-pixel receiver, where the spot is smaller than a pixel, the centroid of the
    pixel means errs by 0.04 pixel). Measured: the exact centroid 0.355
    pixel off the chief ray, the render's 0.389 pixel off it and 0.038 pixel off the exact centroid."""
    z = _best_focus(APERTURE)
    resolution, half_width = 256, 0.5
    image, x, y, pixel_area = _render(_cap(OFF_AXIS), z, resolution, half_width)
    pixel = math.sqrt(pixel_area)

    t = H + CAP
    r_v = math.hypot(*OFF_AXIS)
    tan_air = r_v / (LZ - t)
    sin_glass = tan_air / math.hypot(1.0, tan_air) / N_GLASS
    landing = r_v + t * sin_glass / math.sqrt(1.0 - sin_glass ** 2) + abs(z) * tan_air
    chief = np.array(OFF_AXIS) / r_v * landing

    aim, weight = _aperture_rays(OFF_AXIS, APERTURE)
    b, s = _trace_lens(aim, OFF_AXIS)
    exact = np.average(b + z * s, axis=0, weights=weight)
    assert np.hypot(*(b + z * s - chief).T).max() < WINDOW  # the whole geometric spot is in the window

    inside = np.hypot(x - chief[0], y - chief[1]) < WINDOW
    e = image[inside]
    centroid = np.array([np.average(x[inside], weights=e), np.average(y[inside], weights=e)])
    assert np.linalg.norm(exact - chief) < 0.5 * pixel  # the coma's offset is a fraction of a pixel
    assert np.linalg.norm(centroid - chief) < 0.5 * pixel, (centroid, chief, pixel)
    assert np.linalg.norm(centroid - exact) < 0.1 * pixel, (centroid, exact, pixel)
