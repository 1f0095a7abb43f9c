"""An independent path tracer of a closed glass mesh: the glass as it is cut, traced ray by ray.

It shares nothing with the photon operators but the mesh file: no emission cells, footprints,
differentials, splats, wall mirrors or height-field surface. Rays leave a point light toward
uniformly random points of an aim square on a horizontal plane (each carries the flux of its
share of that square's solid angle), meet the mesh's faces through Embree (trimesh's ray
queries over embreex), refract by Snell's law or reflect totally at every face they meet (flat
faces, no Fresnel), and are binned where they cross the receiver plane. Light that misses the
mesh is not counted: the receiver sees the light that went through the glass.

Used to check a design or a model against the glass it describes (docs/method.md, "The
substrate's side walls"), in the mesh's units (mm for sfc-design's glass.stl).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from operators.values import checked_number, checked_whole

__all__ = ["TracedImage", "trace_mesh"]

MAX_BOUNCES = 12  # faces a ray meets at most (a ray still in the glass after them is dropped)
# How far off a face, along its normal and times the mesh's extent, a ray starts its next query:
# Embree works in float32, so a ray started closer may meet the face it has just left.
NUDGE = 1e-5


@dataclass(frozen=True)
class TracedImage:
    """What :func:`trace_mesh` found.

    Attributes:
        image: (n, n) flux per pixel, W (rows y, columns x, both increasing).
        wall_flux: The part of it that met a vertical face (a side wall) on its way, W.
        entered: The flux that entered the mesh, W.
        dropped: The flux still in the glass after MAX_BOUNCES faces, W.
    """

    image: np.ndarray
    wall_flux: float
    entered: float
    dropped: float


def trace_mesh(mesh_path: str | Path, light: tuple[float, float, float], index: float, aim_half: float,
               aim_z: float, receiver_z: float, receiver_half: float, pixels: int, rays: int, seed: int,
               batches: int = 1, power: float = 1.0) -> TracedImage:
    """Trace ``rays`` rays in each of ``batches`` batches through the closed mesh at ``mesh_path``.

    Args:
        mesh_path: A closed triangle mesh (.stl, .obj, .ply), faces oriented outward.
        light: The point light (x, y, z), mesh units.
        index: The glass's refractive index.
        aim_half: The rays aim at uniform points of [-aim_half, aim_half]^2 on z = ``aim_z``
            (cover the whole glass seen from the light, or light is missed).
        aim_z: The aim plane's height.
        receiver_z: The receiver plane z = receiver_z.
        receiver_half: The square [-receiver_half, receiver_half]^2 on it that is binned ...
        pixels: ... into pixels x pixels.
        rays: Rays per batch (memory grows with it).
        seed: Seeds the aim points.
        batches: Batches of ``rays`` rays.
        power: The light's power, W, radiated evenly over the sphere.
    """
    import trimesh
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    index = checked_number(index, "index", above=1.0, example="1.457")
    rays, batches, pixels = (checked_whole(rays, "rays", 1), checked_whole(batches, "batches", 1),
                             checked_whole(pixels, "pixels", 1))
    mesh = trimesh.load(str(mesh_path), force="mesh")
    if not mesh.is_watertight:
        raise ValueError(f"{mesh_path} is not a closed mesh; the tracer needs the glass as a solid")
    query = RayMeshIntersector(mesh)
    normals = np.asarray(mesh.face_normals)
    nudge = NUDGE * float(np.ptp(mesh.bounds, axis=0).max())
    walls = np.abs(normals[:, 2]) < 1e-9
    source = np.asarray(light, dtype=np.float64)
    rng = np.random.default_rng(seed)
    image = np.zeros((pixels, pixels))
    wall_flux = entered = dropped = 0.0
    for _ in range(batches):
        aim = np.column_stack([rng.uniform(-aim_half, aim_half, (rays, 2)), np.full(rays, aim_z)])
        offset = aim - source
        r = np.linalg.norm(offset, axis=1)
        direction = offset / r[:, None]
        flux = power / (4.0 * math.pi) * (2.0 * aim_half) ** 2 / (rays * batches) * (source[2] - aim_z) / r ** 3
        origin = np.repeat(source[None], rays, axis=0)
        inside = np.zeros(rays, bool)
        met_wall = np.zeros(rays, bool)
        hit_once = np.zeros(rays, bool)
        alive = np.arange(rays)
        for _bounce in range(MAX_BOUNCES):
            points, which, faces = query.intersects_location(origin[alive], direction[alive], multiple_hits=False)
            idx = alive[which]  # a ray that meets no face has left for good (or never came)
            normal = normals[faces]
            cos_i = -(direction[idx] * normal).sum(1)
            entering = cos_i > 0.0
            facing = np.where(entering[:, None], normal, -normal)
            ci = np.abs(cos_i)
            eta = np.where(entering, 1.0 / index, index)
            k = 1.0 - eta ** 2 * (1.0 - ci ** 2)
            total = k < 0.0
            refracted = eta[:, None] * direction[idx] + (eta * ci - np.sqrt(np.maximum(k, 0.0)))[:, None] * facing
            reflected = direction[idx] + 2.0 * ci[:, None] * facing
            turned = np.where(total[:, None], reflected, refracted)
            direction[idx] = turned / np.linalg.norm(turned, axis=1, keepdims=True)
            # back on the side it came from after a total reflection, through the face after a refraction
            origin[idx] = points + (nudge * np.where(total, 1.0, -1.0))[:, None] * facing
            entered += float(flux[idx[entering & ~hit_once[idx]]].sum())
            hit_once[idx] = True
            met_wall[idx] |= walls[faces]
            inside[idx] = np.where(total, inside[idx], ~inside[idx])
            alive = idx
        dropped += float(flux[alive[inside[alive]]].sum())
        out = hit_once & ~inside & (direction[:, 2] < 0.0)
        t = (receiver_z - origin[out, 2]) / direction[out, 2]
        landed = origin[out, :2] + t[:, None] * direction[out, :2]
        on_screen = (np.abs(landed) < receiver_half).all(1)
        binned, _, _ = np.histogram2d(landed[:, 1], landed[:, 0], bins=pixels,
                                      range=[[-receiver_half, receiver_half]] * 2, weights=flux[out])
        image += binned
        wall_flux += float(flux[out][on_screen & met_wall[out]].sum())
    return TracedImage(image, wall_flux, entered, dropped)
