"""A flat slab against the analytic irradiance of a point source seen through it, and energy."""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.optimize import brentq

from tests.operators.conftest import bump, make_operator


def analytic_irradiance(radius: float, light_z: float, h: float, s: float, n: float, power: float) -> float:
    """E(R) = I sin(theta) / (R dR/dtheta), R(theta) = (L - h + |s|) tan(theta) + h tan(theta_g),
    sin(theta_g) = sin(theta) / n: Snell's law plus the Jacobian of the radial ray map."""
    air = light_z - h - s
    intensity = power / (4 * math.pi)

    def radial(theta: float) -> float:
        return air * math.tan(theta) + h * math.tan(math.asin(math.sin(theta) / n))

    if radius < 1e-12:
        return intensity / (air + h / n) ** 2
    theta = brentq(lambda th: radial(th) - radius, 0.0, 1.0, xtol=1e-15)
    theta_g = math.asin(math.sin(theta) / n)
    d_radial = air / math.cos(theta) ** 2 + h * math.cos(theta) / (n * math.cos(theta_g) ** 3)
    return intensity * math.sin(theta) / (radius * d_radial)


def test_flat_slab_matches_analytic_irradiance_at_centre_and_corners():
    op = make_operator(photons=2_000_000, resolution=48, half_width=0.9)
    image = op.render(torch.zeros(32, 32))[0].numpy()
    scene = op.scene
    centres = np.array(scene.receiver.pixel_centres())
    n = scene.indices[0]
    for row, col in [(23, 23), (24, 24), (2, 2), (2, 45), (45, 2), (45, 45), (10, 30)]:
        radius = math.hypot(centres[col], centres[row])
        expected = analytic_irradiance(radius, 10.0, 0.1, -0.05, n, 1.0)
        assert image[row, col] == np.float64(image[row, col])
        assert abs(image[row, col] / expected - 1.0) < 5e-3, (row, col, image[row, col], expected)


def test_energy_reaching_the_receiver_equals_light_power_on_the_square():
    """All light through the glass reaches a large receiver. Rays entering within h tan(theta_g)
    of the edge leave through the side walls (not tracked): the accepted part of the top is the
    square of half width a = 1 / (1 + h / (n (L - h))) (paraxial; 4e-5 relative error here)."""
    op = make_operator(photons=400_000, resolution=64, half_width=1.3)
    distance = 10.0 - 0.1
    a = 1.0 / (1.0 + 0.1 / (op.scene.indices[0] * distance))
    solid_angle = 4 * math.atan(a * a / (distance * math.sqrt(2 * a * a + distance ** 2)))
    expected = solid_angle / (4 * math.pi)
    for heights in (torch.zeros(32, 32), bump(32, height=0.08), bump(32, (0.3, -0.2), 0.15, 0.04)):
        total = float(op.render(heights).sum()) * op.pixel_area
        assert abs(total / expected - 1.0) < 1e-3, total


def test_energy_split_evenly_over_wavelengths():
    op = make_operator(photons=300_000, resolution=64, half_width=1.3, wavelengths=(0.45, 0.55, 0.65))
    per_channel = op.render(bump(32)).sum(dim=(1, 2)) * op.pixel_area
    assert torch.allclose(per_channel, per_channel.mean().expand(3), rtol=1e-3)
