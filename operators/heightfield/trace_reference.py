"""Photon path light -> printed top surface -> flat bottom -> receiver plane, with differentials."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from operators.emission import PhotonBatch
from operators.heightfield.surface import HeightFieldGrid, intersect_height_field
from operators.optics.reference import (away_from_zero, fresnel_transmittance, height_field_normal, height_field_normal_differential,
                              refract, transfer)
from operators.scene import Scene


@dataclass
class ReceiverHits:
    """Photons on the receiver plane: position (2, N) and footprint (2, 2, N) = (Du, Dv) in scene
    units (x, y), flux (N,) in W (zero for photons lost on the way), channel (N,)."""

    position: torch.Tensor
    footprint: torch.Tensor
    flux: torch.Tensor
    channel: torch.Tensor


def trace_substrate(heights: torch.Tensor, scene: Scene, batch: PhotonBatch, glass_index: torch.Tensor,
                    fresnel: bool = False) -> ReceiverHits:
    """Trace ``batch`` through the substrate with printed ``heights`` (m, m) onto the receiver.

    ``glass_index`` (c,) is the refractive index per channel. Photons that undergo total internal
    reflection at the bottom, or leave the glass through its side walls, carry zero flux (they
    cannot reach the receiver below). With ``fresnel`` the flux is weighted by the unpolarised
    Fresnel transmittance of both interfaces; otherwise (the paper's choice) no loss.
    """
    grid = HeightFieldGrid(scene.substrate.thickness, scene.substrate.half_width, heights.shape[0])
    origin, direction, d_direction = batch.origin, batch.direction, batch.direction_diff
    n_glass = glass_index[batch.channel]

    # Top surface: exact hit on the C1 interpolant, refraction air -> glass.
    distance, jet = intersect_height_field(heights, grid, origin, direction)
    normal = height_field_normal(jet)
    start = origin.unsqueeze(-1).expand_as(direction)
    position, d_position = transfer(start, torch.zeros_like(d_direction), direction, d_direction,
                                    distance, normal)
    d_normal = height_field_normal_differential(jet, normal, d_position)
    direction, d_direction, cos_i, cos_t, _ = refract(direction, d_direction, normal, d_normal, 1.0 / n_glass)
    flux = batch.flux
    if fresnel:
        flux = flux * fresnel_transmittance(cos_i, cos_t, 1.0 / n_glass)

    # Flat bottom z = 0: refraction glass -> air.
    up = torch.tensor([0.0, 0.0, 1.0], dtype=direction.dtype, device=direction.device).unsqueeze(-1)
    position, d_position = transfer(position, d_position, direction, d_direction,
                                    -position[2] / away_from_zero(direction[2]), up)
    half = scene.substrate.half_width
    inside = (position[0].abs() <= half) & (position[1].abs() <= half)
    direction, d_direction, cos_i, cos_t, tir = refract(direction, d_direction, up, None, n_glass)
    if fresnel:
        flux = flux * fresnel_transmittance(cos_i, cos_t, n_glass)
    # Lost photons continue straight down with zero flux and footprint, so that no grazing
    # direction blows up their (unused) receiver footprint into inf/NaN gradients.
    lost = ~inside | tir
    flux = torch.where(lost, torch.zeros_like(flux), flux)
    direction = torch.where(lost, -up, direction)
    d_direction = torch.where(lost, torch.zeros_like(d_direction), d_direction)

    # Receiver plane z = s.
    position, d_position = transfer(position, d_position, direction, d_direction,
                                    (scene.receiver.z - position[2]) / away_from_zero(direction[2]), up)
    return ReceiverHits(position=position[:2], footprint=d_position[:, :2], flux=flux, channel=batch.channel)
