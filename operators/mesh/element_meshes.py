"""Closed triangle meshes of optical elements, made procedurally (trimesh), in scene units.

- :func:`lens`: a lens of revolution about the z axis with spherical or conic (aspheric) faces;
- :func:`prism`: a prism of equilateral cross-section in the x-z plane, extruded along y;
- :func:`height_field_solid`: a solid over a square whose top and bottom are height fields (a
  plate, a lens array: :func:`lens_array`);

and :func:`crease_normals`, the shading normals of a mesh (a lens carries its faces' exact
normals instead, in ``mesh.metadata["corner_normals"]``): at each corner of a face the
area-weighted mean of the normals of the faces around that vertex that meet this face at less
than the crease angle (smooth across a lens face, split along a rim or a prism edge).
All meshes are watertight with outward normals; (x, y, z) with z toward the light. The
generators' parameters annotated :data:`Length` are lengths (scene units; a config may give them
in mm, operators/mesh/elements.py).
"""

from __future__ import annotations

import math
from typing import Annotated
from collections.abc import Callable

import numpy as np
import trimesh

__all__ = ["Length", "conic_sag", "conic_slope", "lens", "prism", "height_field_solid", "lens_array",
           "crease_normals"]

Length = Annotated[float, "length"]  # a generator parameter in scene units
# (corner, face) pairs per block of crease_normals: bounds its memory (about 150 bytes a pair).
CREASE_PAIRS_PER_BLOCK = 1 << 20


def conic_sag(r: np.ndarray, radius: float, conic: float = 0.0) -> np.ndarray:
    """Sag z(r) of a conic surface of apex curvature 1 / radius (radius > 0: the surface bends away
    from its apex's tangent plane toward -z) and conic constant k (0: a sphere):
    r^2 / (R (1 + sqrt(1 - (1 + k) r^2 / R^2))); infinite radius: a plane."""
    if math.isinf(radius):
        return np.zeros_like(r)
    argument = 1.0 - (1.0 + conic) * r ** 2 / radius ** 2
    if np.any(argument < 0):
        raise ValueError(f"a face of radius {radius} (conic {conic}) does not reach the aperture; "
                         "use a larger radius of curvature or a smaller lens radius")
    return r ** 2 / (radius * (1.0 + np.sqrt(argument)))


def conic_slope(r: np.ndarray, radius: float, conic: float = 0.0) -> np.ndarray:
    """d sag / dr of :func:`conic_sag`: r / (R sqrt(1 - (1 + k) r^2 / R^2)); 0 for a plane."""
    if math.isinf(radius):
        return np.zeros_like(r)
    return r / (radius * np.sqrt(1.0 - (1.0 + conic) * r ** 2 / radius ** 2))


def _polar_cap(rings: int, segments: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit-disk sample radii (rings * segments + 1,), angles, and the triangles of a fan + rings
    grid (vertex 0 the centre, then ring by ring), counter-clockwise seen from +z."""
    theta = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    radius = np.concatenate([[0.0], np.repeat(np.arange(1, rings + 1) / rings, segments)])
    angle = np.concatenate([[0.0], np.tile(theta, rings)])
    j = np.arange(segments)
    faces = [np.stack([np.zeros(segments, int), 1 + j, 1 + (j + 1) % segments], axis=1)]
    for ring in range(1, rings):
        a, b = 1 + (ring - 1) * segments, 1 + ring * segments
        faces.append(np.stack([a + j, b + j, b + (j + 1) % segments], axis=1))
        faces.append(np.stack([a + j, b + (j + 1) % segments, a + (j + 1) % segments], axis=1))
    return radius, angle, np.concatenate(faces)


def lens(radius: Length, thickness: Length, front_radius: Length, back_radius: Length, front_conic: float = 0.0,
         back_conic: float = 0.0, rings: int = 48, segments: int = 128) -> trimesh.Trimesh:
    """A lens of aperture ``radius`` and centre ``thickness`` between z = -thickness / 2 and
    z = +thickness / 2 on the axis. The front (top, toward +z) face sags by conic_sag(r,
    front_radius, front_conic) below its apex, the back face rises by conic_sag(r, back_radius,
    back_conic) above its apex: positive radii make a biconvex lens, a negative radius a concave
    face, ``math.inf`` a plane. Refused when the faces cross inside the aperture."""
    if not (radius > 0 and thickness > 0):
        raise ValueError(f"lens radius={radius} and thickness={thickness} must be positive")
    unit, angle, cap = _polar_cap(rings, segments)
    r = unit * radius
    top = thickness / 2 - conic_sag(r, front_radius, front_conic)
    bottom = -thickness / 2 + conic_sag(r, back_radius, back_conic)
    if np.any(top - bottom <= 0):
        raise ValueError(f"the lens faces cross inside the aperture (edge thickness {float((top - bottom).min()):.4g});"
                         " thicken the lens or flatten its faces")
    x, y = r * np.cos(angle), r * np.sin(angle)
    count = len(r)
    vertices = np.concatenate([np.stack([x, y, top], 1), np.stack([x, y, bottom], 1)])
    rim_top = 1 + (rings - 1) * segments + np.arange(segments)
    rim_bottom = rim_top + count
    j = np.arange(segments)
    following = (j + 1) % segments
    rim = np.concatenate([np.stack([rim_top, rim_bottom, rim_bottom[following]], 1),
                          np.stack([rim_top, rim_bottom[following], rim_top[following]], 1)])
    faces = np.concatenate([cap, cap[:, ::-1] + count, rim])
    mesh = _checked(trimesh.Trimesh(vertices, faces, process=False))
    # The faces' exact normals at the corners (a faceted mesh's averaged normals are off by up to
    # a sixth near the apex, where the fan's triangles are long and thin).
    cos, sin = np.cos(angle), np.sin(angle)
    front, back = conic_slope(r, front_radius, front_conic), conic_slope(r, back_radius, back_conic)
    exact = np.concatenate([np.stack([front * cos, front * sin, np.ones_like(r)], 1),
                            np.stack([back * cos, back * sin, -np.ones_like(r)], 1)])
    exact /= np.linalg.norm(exact, axis=1, keepdims=True)
    corner = exact[faces]
    radial = np.stack([np.tile(cos, 2), np.tile(sin, 2), np.zeros(2 * count)], 1)
    corner[-len(rim):] = radial[rim]
    mesh.metadata["corner_normals"] = corner
    return mesh


def prism(side: Length, length: Length) -> trimesh.Trimesh:
    """A prism whose cross-section in the x-z plane is the equilateral triangle of ``side`` with its
    centroid at the origin and a vertex at +z, extruded along y over [-length / 2, length / 2]."""
    if not (side > 0 and length > 0):
        raise ValueError(f"prism side={side} and length={length} must be positive")
    height = side * math.sqrt(3) / 2
    corners = np.array([[0.0, 2 * height / 3], [-side / 2, -height / 3], [side / 2, -height / 3]])
    vertices = np.array([[cx, y, cz] for y in (-length / 2, length / 2) for cx, cz in corners])
    faces = np.array([[0, 1, 2], [3, 5, 4],  # the end faces, y = -L/2 and y = +L/2
                      [0, 4, 1], [0, 3, 4], [1, 5, 2], [1, 4, 5], [2, 3, 0], [2, 5, 3]])
    return _checked(trimesh.Trimesh(vertices, faces, process=False))


def height_field_solid(top: Callable[[np.ndarray, np.ndarray], np.ndarray],
                       bottom: Callable[[np.ndarray, np.ndarray], np.ndarray],
                       half_width: float, resolution: int) -> trimesh.Trimesh:
    """The solid over [-W, W]^2 between the surfaces z = bottom(x, y) < top(x, y), each sampled on a
    resolution x resolution grid, closed by four vertical side walls."""
    if not (half_width > 0 and resolution >= 2):
        raise ValueError(f"half_width={half_width} must be positive and resolution={resolution} >= 2")
    t = np.linspace(-half_width, half_width, resolution)
    x, y = np.meshgrid(t, t)
    z_top, z_bottom = np.asarray(top(x, y), float), np.asarray(bottom(x, y), float)
    if np.any(z_top - z_bottom <= 0):
        raise ValueError("the solid's top must lie above its bottom everywhere")
    n = resolution
    index = np.arange(n * n).reshape(n, n)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, 1:].ravel(), index[1:, :-1].ravel()
    grid = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])  # counter-clockwise from +z
    vertices = np.concatenate([np.stack([x.ravel(), y.ravel(), z_top.ravel()], 1),
                               np.stack([x.ravel(), y.ravel(), z_bottom.ravel()], 1)])
    offset = n * n
    boundary = np.concatenate([index[0, :], index[1:, -1], index[-1, -2::-1], index[-2:0:-1, 0]])
    following = np.roll(boundary, -1)
    walls = np.concatenate([np.stack([boundary, boundary + offset, following + offset], 1),
                            np.stack([boundary, following + offset, following], 1)])
    faces = np.concatenate([grid, grid[:, ::-1] + offset, walls])
    return _checked(trimesh.Trimesh(vertices, faces, process=False))


def lens_array(half_width: Length, thickness: Length, lenslet_radius: Length, pitch: Length, count: int,
               resolution: int = 321) -> trimesh.Trimesh:
    """A plate over [-W, W]^2 from z = -thickness to 0 whose underside carries count x count
    hemispherical lenslets of ``lenslet_radius`` at ``pitch``, centred on the axis (apexes at
    z = -thickness - lenslet_radius)."""
    if not (thickness > 0 and 0 < lenslet_radius <= pitch / 2 and count >= 1):
        raise ValueError(f"lens array needs thickness > 0, 0 < lenslet_radius <= pitch / 2 and count >= 1; "
                         f"got {thickness}, {lenslet_radius}, {pitch}, {count}")
    if (count - 1) * pitch / 2 + lenslet_radius > half_width:
        raise ValueError(f"{count} x {count} lenslets at pitch {pitch} do not fit the plate of half width {half_width}")
    centres = (np.arange(count) - (count - 1) / 2) * pitch

    def underside(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        cx = centres[np.argmin(np.abs(x[..., None] - centres), axis=-1)]
        cy = centres[np.argmin(np.abs(y[..., None] - centres), axis=-1)]
        rho2 = (x - cx) ** 2 + (y - cy) ** 2
        return -thickness - np.sqrt(np.clip(lenslet_radius ** 2 - rho2, 0.0, None))

    return height_field_solid(lambda x, y: np.zeros_like(x), underside, half_width, resolution)


def crease_normals(mesh: trimesh.Trimesh, crease_angle_deg: float = 30.0) -> np.ndarray:
    """Shading normals (F, 3, 3) at the corners of every face: the area-weighted mean of the
    normals of the faces around the corner's vertex that meet the face at less than
    ``crease_angle_deg`` (so that a face is always smooth with itself). Each corner is compared
    with every face around its vertex, in blocks of corners, so that memory stays bounded however
    many faces meet at a vertex."""
    if not 0.0 <= crease_angle_deg < 180.0:
        raise ValueError(f"crease_angle_deg={crease_angle_deg} must lie in [0, 180)")
    normals, areas = mesh.face_normals, mesh.area_faces
    corner_vertex = np.asarray(mesh.faces, dtype=np.int64).ravel()  # corner 3 f + k of face f
    by_vertex = np.argsort(corner_vertex, kind="stable")  # slots: the corners grouped by vertex
    degree = np.bincount(corner_vertex, minlength=len(mesh.vertices))
    first = np.cumsum(degree) - degree  # each vertex's first slot
    slot_vertex = corner_vertex[by_vertex]
    row_pairs = degree[slot_vertex]  # a slot's corner against each face around its vertex
    pairs = np.cumsum(row_pairs)
    threshold = math.cos(math.radians(crease_angle_deg)) - 1e-12
    summed = np.empty((len(corner_vertex), 3))
    low = 0
    while low < len(by_vertex):
        done = pairs[low - 1] if low else 0
        high = max(low + 1, int(np.searchsorted(pairs, done + CREASE_PAIRS_PER_BLOCK, side="right")))
        count = row_pairs[low:high]
        row = np.repeat(np.arange(low, high), count)
        rank = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
        face = by_vertex[first[slot_vertex[row]] + rank] // 3
        near = np.einsum("pd,pd->p", normals[face], normals[by_vertex[row] // 3]) >= threshold
        weighted = areas[face[near], None] * normals[face[near]]
        local = row[near] - low
        summed[by_vertex[low:high]] = np.stack(
            [np.bincount(local, weights=weighted[:, d], minlength=high - low) for d in range(3)], axis=1)
        low = high
    summed = summed.reshape(-1, 3, 3)
    return summed / np.linalg.norm(summed, axis=-1, keepdims=True)


def _checked(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The mesh, refused unless it is a closed volume with outward normals."""
    if not (mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0):
        raise ValueError("internal error: a generated mesh is not a closed, outward-facing volume")
    return mesh
