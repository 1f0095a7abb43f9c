"""Photon path light -> printed top surface -> flat bottom -> receiver plane, with differentials."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from operators.emission import PhotonBatch
from operators.heightfield.side_walls import BESIDE, FOLD_LIMIT, LOST
from operators.heightfield.surface import HeightFieldGrid, intersect_height_field
from operators.optics.reference import (away_from_zero, fresnel_transmittance, height_field_normal,
                                        height_field_normal_differential, refract, transfer)
from operators.scene import Scene, Substrate


@dataclass
class ReceiverHits:
    """Photons on the receiver plane: position (2, N) and footprint (2, 2, N) = (Du, Dv) in scene
    units (x, y), flux (N,) in W (zero for photons lost on the way), channel (N,) and the code of
    the path each took (N,) (operators/heightfield/side_walls.py; 0: lost)."""

    position: torch.Tensor
    footprint: torch.Tensor
    flux: torch.Tensor
    channel: torch.Tensor
    path: torch.Tensor


def trace_substrate(heights: torch.Tensor, scene: Scene, batch: PhotonBatch, glass_index: torch.Tensor,
                    fresnel: bool = False) -> ReceiverHits:
    """Trace ``batch`` through the substrate with printed ``heights`` (m, m) onto the receiver.

    ``glass_index`` (c,) is the refractive index per channel. A photon that meets a side wall is
    refracted out of it or totally reflected back in (with ``substrate.walls: absorbing`` it is
    lost); photons totally reflected at the bottom carry zero flux. With ``fresnel`` the flux is weighted by
    the unpolarised
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

    # The bottom z = 0 or a side wall: refraction glass -> air (operators/heightfield/side_walls.py).
    normal, offset, mirror, shift, walled = leaving_faces(position, direction, n_glass, scene.substrate)
    path = path_codes(normal, shift)
    distance = (offset - (position * normal).sum(0)) / away_from_zero((direction * normal).sum(0))
    position, d_position = transfer(position, d_position, direction, d_direction, distance, normal)
    direction, d_direction, cos_i, cos_t, tir = refract(direction, d_direction, normal, None, n_glass)
    if fresnel:
        flux = flux * fresnel_transmittance(cos_i, cos_t, n_glass)
    # Lost photons continue straight down with zero flux and footprint, so that no grazing
    # direction blows up their (unused) receiver footprint into inf/NaN gradients.
    up = torch.tensor([0.0, 0.0, 1.0], dtype=direction.dtype, device=direction.device).unsqueeze(-1)
    lost = walled | tir
    flux = torch.where(lost, torch.zeros_like(flux), flux)
    direction = torch.where(lost, -up, direction)
    d_direction = torch.where(lost, torch.zeros_like(d_direction), d_direction)

    # Receiver plane z = s, then the mirrors of the walls' total reflections.
    position, d_position = transfer(position, d_position, direction, d_direction,
                                    (scene.receiver.z - position[2]) / away_from_zero(direction[2]), up)
    position = position[:2] * mirror + shift
    d_position = d_position[:, :2] * mirror
    return ReceiverHits(position=position, footprint=d_position, flux=flux, channel=batch.channel,
                        path=torch.where(lost, LOST, path))


def leaving_faces(position: torch.Tensor, direction: torch.Tensor, n_glass: torch.Tensor, substrate: Substrate
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The face each photon at ``position`` (3, N) in the glass along ``direction`` (3, N) leaves
    the block through, as :func:`operators.heightfield.side_walls.leaving_plane` for one photon:
    (normal (3, N), offset (N,): the plane normal . p = offset, mirror (2, N) of +-1 and shift
    (2, N): the landing (x, y) -> mirror (x, y) + shift of the walls' total reflections, walled
    (N,): lost at a wall, or beside the block). No gradient flows through the choice."""
    with torch.no_grad():
        half = substrate.half_width
        along = -position[2] / away_from_zero(direction[2])
        bottom = position[:2] + along * direction[:2]
        crosses = bottom.abs() > half
        side = torch.where(bottom > 0.0, 1.0, -1.0).to(position.dtype)
        exits = crosses & (n_glass ** 2 * (1.0 - direction[:2] ** 2) < 1.0)
        reach = (side * half - position[:2]) * direction[:2] / (direction[:2] ** 2).clamp_min(1e-300)
        exit_x = exits[0] & (~exits[1] | (reach[0] <= reach[1]))
        exit_y = exits[1] & ~exit_x
        fold = torch.stack([
            torch.where(exit_x, False, torch.where(exit_y, crosses[0] & (reach[0] < reach[1]), crosses[0])),
            torch.where(exit_y, False, torch.where(exit_x, crosses[1] & (reach[1] < reach[0]), crosses[1]))])
        normal = torch.zeros_like(position)
        normal[0] = torch.where(exit_x, -side[0], 0.0)
        normal[1] = torch.where(exit_y, -side[1], 0.0)
        normal[2] = torch.where(exit_x | exit_y, 0.0, 1.0)
        offset = torch.where(exit_x | exit_y, -half, 0.0).to(position.dtype)
        mirror = torch.where(fold, -1.0, 1.0).to(position.dtype)
        shift = torch.where(fold, 2.0 * half * side, 0.0).to(position.dtype)
        # A top hit outside the square (aimed beyond it, operators/emission.py): the ray passed beside the block.
        walled = (bottom.abs() > FOLD_LIMIT * half).any(0) | (position[:2].abs() > BESIDE * half).any(0)
        if substrate.walls != "clear":
            walled = walled | crosses.any(0)
    return normal, offset, mirror, shift, walled


def path_codes(normal: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """Path codes (N,) of :func:`operators.heightfield.side_walls.leaving_plane` from the faces'
    normals (3, N) and the mirrors' shifts (2, N) that :func:`leaving_faces` gives (not lost)."""
    fold = torch.where(shift > 0.0, 1, torch.where(shift < 0.0, 2, 0))
    exit_code = torch.where(normal[0] != 0.0, 1, torch.where(normal[1] != 0.0, 2, 0))
    return 1 + fold[0] + 3 * fold[1] + 9 * exit_code
