"""Ray optics with photon differentials (Igehy 1999, "Tracing ray differentials").

Vectors are (3, N) tensors; the pair of differentials (d/du, d/dv) of a vector is (2, 3, N).
Every function is plain torch, so autograd differentiates through it.
"""

from __future__ import annotations

import torch


def dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Dot product over the component axis (-2): (3, N) . (3, N) -> (N,), (2, 3, N) . (3, N) -> (2, N)."""
    return (a * b).sum(-2)


GRAZING = 1e-6


def away_from_zero(x: torch.Tensor, eps: float = GRAZING) -> torch.Tensor:
    """x with magnitudes below eps raised to eps (sign kept): a safe denominator for grazing rays,
    whose values stay finite so that neither the forward pass nor autograd produces inf / NaN."""
    return torch.where(x.abs() < eps, torch.where(x < 0, -eps, eps) * torch.ones_like(x), x)


def transfer(position: torch.Tensor, d_position: torch.Tensor, direction: torch.Tensor,
             d_direction: torch.Tensor, distance: torch.Tensor,
             normal: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Move photons ``distance`` along ``direction`` onto a surface with ``normal`` there.

    Positional differentials land on the surface's tangent plane:
    D p' = D p + t D w + D t w, with D t = -(D p + t D w) . n / (w . n).
    """
    moved = d_position + distance * d_direction
    d_distance = -dot(moved, normal) / away_from_zero(dot(direction, normal))
    return position + distance * direction, moved + d_distance.unsqueeze(-2) * direction


def refract(direction: torch.Tensor, d_direction: torch.Tensor, normal: torch.Tensor,
            d_normal: torch.Tensor | None, eta: torch.Tensor | float
            ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Snell refraction of unit ``direction`` at a surface whose unit ``normal`` faces the ray.

    eta = n_incident / n_transmitted. t = eta w + (eta cos_i - cos_t) n with cos_i = -w . n and
    cos_t = sqrt(1 - eta^2 (1 - cos_i^2)); the differential follows by the chain rule, including
    the derivative of the normal. Returns (t, D t, cos_i, cos_t, total_internal_reflection mask);
    under total internal reflection cos_t is clamped and the caller must drop the photon.
    """
    cos_i = -dot(direction, normal)
    k = 1.0 - eta ** 2 * (1.0 - cos_i ** 2)
    tir = k <= 0.0
    cos_t = torch.sqrt(torch.clamp(k, min=1e-12))
    refracted = eta * direction + (eta * cos_i - cos_t) * normal
    d_cos_i = -dot(d_direction, normal)
    if d_normal is not None:
        d_cos_i = d_cos_i - dot(direction, d_normal)
    d_cos_t = eta ** 2 * cos_i * d_cos_i / cos_t
    d_refracted = eta * d_direction + (eta * d_cos_i - d_cos_t).unsqueeze(-2) * normal
    if d_normal is not None:
        d_refracted = d_refracted + (eta * cos_i - cos_t) * d_normal
    return refracted, d_refracted, cos_i, cos_t, tir


def fresnel_transmittance(cos_i: torch.Tensor, cos_t: torch.Tensor, eta: torch.Tensor | float) -> torch.Tensor:
    """Unpolarised Fresnel power transmittance 1 - (R_s + R_p) / 2 (eta = n_incident / n_transmitted)."""
    r_s = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    r_p = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    return 1.0 - 0.5 * (r_s ** 2 + r_p ** 2)


def height_field_normal(jet: torch.Tensor) -> torch.Tensor:
    """Unit upward normal (3, N) of z = S(x, y): (-S_x, -S_y, 1) / |.|; jet (5, N) = (S_x, S_y, S_xx, S_xy, S_yy)."""
    sx, sy = jet[0], jet[1]
    return torch.stack([-sx, -sy, torch.ones_like(sx)]) / torch.sqrt(1.0 + sx ** 2 + sy ** 2)


def height_field_normal_differential(jet: torch.Tensor, normal: torch.Tensor,
                                     d_position: torch.Tensor) -> torch.Tensor:
    """Differentials (2, 3, N) of the unit normal for positional differentials d_position (2, 3, N).

    D n = (D m - n (n . D m)) / |m| with m = (-S_x, -S_y, 1), D m = -(Hessian of S) D p_xy, and
    |m| = 1 / n_z.
    """
    sxx, sxy, syy = jet[2], jet[3], jet[4]
    dx, dy = d_position[:, 0], d_position[:, 1]
    d_raw = torch.stack([-(sxx * dx + sxy * dy), -(sxy * dx + syy * dy), torch.zeros_like(dx)], dim=1)
    return (d_raw - normal * dot(d_raw, normal).unsqueeze(-2)) * normal[2]
