"""Crossings of closed triangle meshes: faces of one surface that pass through faces of another,
or of the same surface (a self-intersecting mesh).

Two triangles that cross (not coplanar) always put an edge of one through the other, so every
edge is tested against the faces: each edge is moved CROSSING_TOLERANCE times the meshes' largest
extent into its own solid (along the mean of its two faces' inward normals, which keeps it off the
planes of the faces around it), shortened as much at both ends, and traced by Embree (float32,
coordinates centred on the traced mesh); every hit is confirmed in float64 (the edge's ends on
opposite sides of the face's plane, the crossing point inside the face to the tolerance) and the
ray goes on past it to the edge's end. A mesh's edges do not count against the faces that share a
vertex with them (those meet by construction). Both faces on a crossing edge cross the face it
passes through. Surfaces that only touch, or cross by less than the tolerance, do not cross; a
solid thinner than the tolerance does.
"""

from __future__ import annotations

from dataclasses import dataclass
from collections.abc import Callable

import numpy as np
import trimesh
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

__all__ = ["CROSSING_TOLERANCE", "Crossings", "self_crossings", "mutual_crossings"]

# Depth (relative to the meshes' largest extent) below which surfaces touch rather than cross; 30
# times float32's rounding of centred coordinates (3e-8), so that Embree's choices are not noise.
CROSSING_TOLERANCE = 1e-6


@dataclass(frozen=True)
class Crossings:
    """Pairs of crossing faces.

    Attributes:
        pairs: (N, 2) face indices, rows in ascending order (one mesh: the lower index first; two
            meshes: the first mesh's face, then the second's).
        points: (N, 3) a point where each pair crosses, in the meshes' coordinates.
    """

    pairs: np.ndarray
    points: np.ndarray

    def __len__(self) -> int:
        return len(self.pairs)


def _norm(vectors: np.ndarray) -> np.ndarray:
    """(N,) lengths of vectors (N, 3)."""
    return np.sqrt(np.einsum("ij,ij->i", vectors, vectors))


def _unit(vectors: np.ndarray) -> np.ndarray:
    """Vectors (N, 3) scaled to length 1 (zero vectors stay zero)."""
    return vectors / np.maximum(_norm(vectors), np.finfo(float).tiny)[:, None]


def _edge_faces(mesh: trimesh.Trimesh) -> np.ndarray:
    """(E, 2): the two faces on each of a closed mesh's unique edges (mesh.edges_unique)."""
    order = np.argsort(mesh.edges_unique_inverse, kind="stable")
    return (order // 3).reshape(-1, 2)


def _edge_segments(mesh: trimesh.Trimesh, edge_faces: np.ndarray, depth: float) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (E, 3) of the closed mesh's unique edges, whose faces are ``edge_faces`` (E, 2),
    moved ``depth`` into the solid and shortened by ``depth`` at both ends (an edge shorter than
    2 depth becomes a point)."""
    normals = np.asarray(mesh.face_normals)
    shift = -depth * _unit(normals[edge_faces[:, 0]] + normals[edge_faces[:, 1]])
    vertices = np.asarray(mesh.vertices)
    start, end = vertices[mesh.edges_unique[:, 0]], vertices[mesh.edges_unique[:, 1]]
    trim = _unit(end - start) * np.minimum(depth, _norm(end - start) / 2)[:, None]
    return start + trim + shift, end - trim + shift


def _confirmed(start: np.ndarray, end: np.ndarray, triangles: np.ndarray, slack: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Which segments start -> end (N, 3) cross their triangle (N, 3, 3), in float64, and where:
    (N,) bool and (N, 3) points. The crossing point may lie up to ``slack`` (length) outside the
    triangle: there the segment crosses the neighbouring face, which its ray steps over."""
    v0, v1, v2 = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    normal = _unit(np.cross(v1 - v0, v2 - v0))
    height_start = np.einsum("ij,ij->i", start - v0, normal)
    height_end = np.einsum("ij,ij->i", end - v0, normal)
    crosses = np.sign(height_start) * np.sign(height_end) < 0
    fraction = height_start / np.where(crosses, height_start - height_end, 1.0)
    point = start + fraction[:, None] * (end - start)
    for a, b in ((v0, v1), (v1, v2), (v2, v0)):
        inside = np.einsum("ij,ij->i", np.cross(_unit(b - a), point - a), normal)  # distance to the side
        crosses &= inside >= -slack
    return crosses, point


def _edge_face_hits(start: np.ndarray, end: np.ndarray, vertices: np.ndarray, faces: np.ndarray, tolerance: float,
                    skip: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every face of (vertices, faces) that the segments start -> end (E, 3) cross: (K,) segment
    and face indices and (K, 3) points. A segment is traced on from ``tolerance`` (length) past
    each hit, a hit counts up to ``tolerance`` outside its face, and ``skip(segments, faces)`` ->
    (K,) bool marks hits that do not count."""
    vertices, faces = np.asarray(vertices), np.asarray(faces)  # embreex reads plain arrays faster
    centre = (vertices.min(axis=0) + vertices.max(axis=0)) / 2  # float32 keeps more digits near 0
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, (vertices - centre).astype(np.float32), faces.astype(np.int32))
    length, direction = _norm(end - start), _unit(end - start)
    travelled = np.zeros(len(start))
    ray = np.flatnonzero(length > 0)
    found = [(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)))]
    while len(ray):
        origin = start[ray] - centre + travelled[ray, None] * direction[ray]
        hit = scene.run(origin.astype(np.float32), direction[ray].astype(np.float32),
                        dists=(length[ray] - travelled[ray]).astype(np.float32), output=1)
        face = hit["primID"].astype(np.int64)
        ray, face, distance = ray[face >= 0], face[face >= 0], hit["tfar"][face >= 0]
        crosses, point = _confirmed(start[ray], end[ray], vertices[faces[face]], tolerance)
        if skip is not None:
            crosses &= ~skip(ray, face)
        found.append((ray[crosses], face[crosses], point[crosses]))
        travelled[ray] += distance + tolerance
        ray = ray[travelled[ray] < length[ray]]
    segment, face, point = (np.concatenate(part) for part in zip(*found))
    return segment, face, point


def _crossings(pairs: np.ndarray, points: np.ndarray) -> Crossings:
    """The distinct rows of ``pairs`` (N, 2), each with its first point of ``points`` (N, 3)."""
    pairs, first = np.unique(pairs, axis=0, return_index=True)
    return Crossings(pairs, points[first])


def _face_pairs(edge_faces: np.ndarray, face: np.ndarray, point: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """K edge crossings as 2 K face pairs (2 K, 2), each face on the edge (K, 2) with the face the
    edge crosses (K,), and their crossing points (2 K, 3)."""
    return np.stack([edge_faces.ravel(), np.repeat(face, 2)], axis=1), np.repeat(point, 2, axis=0)


def _size(*meshes: trimesh.Trimesh) -> float:
    """The largest extent of the meshes' joint bounding box."""
    return float(np.ptp(np.concatenate([mesh.bounds for mesh in meshes]), axis=0).max())


def self_crossings(mesh: trimesh.Trimesh) -> Crossings:
    """The face pairs of a closed, outward-wound mesh that cross: its edges through the faces that
    share no vertex with them (faces around a vertex meet there by construction)."""
    depth = CROSSING_TOLERANCE * _size(mesh)
    edge_faces = _edge_faces(mesh)
    start, end = _edge_segments(mesh, edge_faces, depth)
    edges, faces = mesh.edges_unique, mesh.faces

    def adjacent(segment: np.ndarray, face: np.ndarray) -> np.ndarray:
        """(K,) bool: which faces (K,) share a vertex with their edges (K,)."""
        return np.any(faces[face][:, :, None] == edges[segment][:, None, :], axis=(1, 2))

    segment, face, point = _edge_face_hits(start, end, mesh.vertices, faces, depth, adjacent)
    pairs, points = _face_pairs(edge_faces[segment], face, point)
    return _crossings(np.sort(pairs, axis=1), points)


def _meeting(low: np.ndarray, high: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(N,) bool: which point groups (N, k, 3) have a bounding box that meets the box [low, high]."""
    return np.all(corners.max(axis=1) >= low, axis=1) & np.all(corners.min(axis=1) <= high, axis=1)


def _one_way(a: trimesh.Trimesh, b: trimesh.Trimesh, depth: float) -> tuple[np.ndarray, np.ndarray]:
    """Edges of ``a`` (moved into ``a``) through faces of ``b`` as face pairs (M, 2) (a face on the
    edge, b's face) and points (M, 3); only edges and faces that meet both bounding boxes count."""
    low = np.maximum(a.bounds[0], b.bounds[0]) - depth
    high = np.minimum(a.bounds[1], b.bounds[1]) + depth
    edge_faces = _edge_faces(a)
    start, end = _edge_segments(a, edge_faces, depth)
    edges = np.flatnonzero(_meeting(low, high, np.stack([start, end], axis=1)))
    faces = np.flatnonzero(_meeting(low, high, b.triangles))
    if len(edges) == 0 or len(faces) == 0:
        return np.zeros((0, 2), np.int64), np.zeros((0, 3))
    segment, face, point = _edge_face_hits(start[edges], end[edges], b.vertices, b.faces[faces], depth)
    return _face_pairs(edge_faces[edges[segment]], faces[face], point)


def mutual_crossings(a: trimesh.Trimesh, b: trimesh.Trimesh) -> Crossings:
    """The pairs (face of ``a``, face of ``b``) that cross, found by the edges of each through the
    other's faces; two closed, outward-wound meshes in the same coordinates."""
    depth = CROSSING_TOLERANCE * _size(a, b)
    forward, forward_points = _one_way(a, b, depth)
    backward, backward_points = _one_way(b, a, depth)
    return _crossings(np.concatenate([forward, backward[:, ::-1]]), np.concatenate([forward_points, backward_points]))
