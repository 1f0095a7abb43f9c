"""Ray / element intersection: Embree (embreex) finds the face, torch recomputes the hit.

Embree traces in float32 and answers which face a ray meets first. The hit itself is recomputed
in the rays' precision from that face's plane, t = (v0 - o) . n_f / (w . n_f), so that it is
exact to rounding and differentiable w.r.t. the ray (the chain rule through fixed elements); so
are the barycentric coordinates and the interpolated shading normal N = |sum b_k n_k| and its
derivative along the face, which the photon differentials need.
"""

from __future__ import annotations

from dataclasses import dataclass
from collections.abc import Sequence

import numpy as np
import torch

from operators.mesh.elements import OpticalElement

__all__ = ["ElementHits", "MeshIntersector"]

# Rays start this far (scene units) along their direction, so that Embree does not report the
# surface they leave.
START_OFFSET = 1e-6
# A face hit nearer than this is the face the ray leaves (Embree does not look that near): ignored.
MIN_FACE_DISTANCE = 0.5 * START_OFFSET
# Moves of a hit to the neighbouring face when Embree's float32 choice lies just beside it.
REFINEMENTS = 2


def _edge_neighbours(faces: np.ndarray) -> np.ndarray:
    """(F, 3): the face across the edge opposite each corner of each face (-1 on an open edge)."""
    count = len(faces)
    edges = np.stack([faces[:, [1, 2]], faces[:, [2, 0]], faces[:, [0, 1]]], axis=1).reshape(-1, 2)
    key = np.sort(edges, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    sorted_key = key[order]
    same = np.all(sorted_key[1:] == sorted_key[:-1], axis=1)
    neighbour = np.full(3 * count, -1, dtype=np.int64)
    first, second = order[:-1][same], order[1:][same]
    neighbour[first], neighbour[second] = second // 3, first // 3
    return neighbour.reshape(count, 3)


@dataclass
class ElementHits:
    """Hits of N rays on the elements' faces (rays that miss keep face = -1 and t = inf).

    Attributes:
        face: (N,) global face index, -1 for a miss.
        t: (N,) distance along the ray (differentiable w.r.t. origin and direction).
        plane_normal: (3, N) the face's geometric normal (outward).
        normal: (3, N) the unit interpolated shading normal (outward).
        normal_gradient: (3, 3, N) dN/dp along the face: dN = normal_gradient[:, k] dp_k.
        element: (N,) index of the element the face belongs to, -1 for a miss.
    """

    face: torch.Tensor
    t: torch.Tensor
    plane_normal: torch.Tensor
    normal: torch.Tensor
    normal_gradient: torch.Tensor
    element: torch.Tensor


class MeshIntersector:
    """All elements' faces in one Embree scene, with the per-face data for the exact hit."""

    def __init__(self, elements: Sequence[OpticalElement]) -> None:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.count = len(elements)
        if not elements:
            return
        offsets = np.cumsum([0] + [len(e.mesh.vertices) for e in elements])
        self.vertices = vertices = np.concatenate([e.mesh.vertices for e in elements])
        self.faces = faces = np.concatenate([e.mesh.faces + o for e, o in zip(elements, offsets)])
        self.face_element = torch.from_numpy(np.concatenate([np.full(len(e.mesh.faces), k)
                                                             for k, e in enumerate(elements)]))
        corners = vertices[faces]  # (F, 3, 3)
        e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
        n = np.cross(e1, e2)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        # Dual basis in the face's plane: b1 = (p - v0) . g1, b2 = (p - v0) . g2.
        g11, g12, g22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
        det = g11 * g22 - g12 ** 2
        dual1 = (g22[:, None] * e1 - g12[:, None] * e2) / det[:, None]
        dual2 = (g11[:, None] * e2 - g12[:, None] * e1) / det[:, None]
        shading = np.concatenate([e.normals for e in elements])  # (F, 3, 3)
        self._neighbour = torch.from_numpy(_edge_neighbours(faces))
        self._v0 = torch.from_numpy(corners[:, 0])
        self._n = torch.from_numpy(n)
        self._dual = torch.from_numpy(np.stack([dual1, dual2], axis=1))  # (F, 2, 3)
        self._shading = torch.from_numpy(shading)
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(self._scene, vertices.astype(np.float32), faces.astype(np.int32))

    def face_arrays(self) -> tuple[np.ndarray, ...]:
        """(face_element (F,), v0 (F, 3), plane normal (F, 3), dual basis (F, 2, 3), corner shading
        normals (F, 3, 3), neighbours (F, 3)) as contiguous arrays for native kernels; one dummy
        face when there are no elements."""
        if self.count == 0:
            return (np.zeros(1, np.int64), np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 2, 3)),
                    np.zeros((1, 3, 3)), np.full((1, 3), -1, np.int64))
        return tuple(np.ascontiguousarray(a.numpy()) for a in (self.face_element, self._v0, self._n, self._dual,
                                                               self._shading, self._neighbour))

    def intersect(self, origin: torch.Tensor, direction: torch.Tensor, which: torch.Tensor | None = None
                  ) -> ElementHits:
        """First element hit of rays origin + t w, origin and direction (3, N); only the rays
        where ``which`` (N,) is True are traced (the others miss)."""
        n_rays = direction.shape[1]
        like = dict(dtype=direction.dtype, device=direction.device)
        misses = ElementHits(torch.full((n_rays,), -1, dtype=torch.int64), torch.full((n_rays,), torch.inf, **like),
                             torch.zeros(3, n_rays, **like), torch.zeros(3, n_rays, **like),
                             torch.zeros(3, 3, n_rays, **like), torch.full((n_rays,), -1, dtype=torch.int64))
        if self.count == 0 or n_rays == 0:
            return misses
        if which is not None:
            index = which.nonzero().squeeze(1)
            if index.numel() == 0:
                return misses
            part = self.intersect(origin[:, index], direction[:, index])
            return ElementHits(misses.face.index_copy(0, index, part.face), misses.t.index_copy(0, index, part.t),
                               misses.plane_normal.index_copy(1, index, part.plane_normal),
                               misses.normal.index_copy(1, index, part.normal),
                               misses.normal_gradient.index_copy(2, index, part.normal_gradient),
                               misses.element.index_copy(0, index, part.element))
        o = origin.detach().cpu().numpy().T
        w = direction.detach().cpu().numpy().T
        found = self._scene.run((o + START_OFFSET * w).astype(np.float32), w.astype(np.float32), output=1)
        face = torch.from_numpy(np.asarray(found["primID"], dtype=np.int64))
        hit = face >= 0
        safe = torch.where(hit, face, torch.zeros_like(face))
        for attempt in range(REFINEMENTS + 1):
            v0 = self._v0[safe].T.to(**like)
            plane = self._n[safe].T.to(**like)
            cos = (direction * plane).sum(0)
            safe_cos = torch.where(cos.abs() > 1e-12, cos, torch.ones_like(cos))
            t = ((v0 - origin) * plane).sum(0) / safe_cos
            t = torch.where(hit & (cos.abs() > 1e-12), t, torch.full_like(t, torch.inf))
            point = origin + torch.where(torch.isfinite(t), t, torch.zeros_like(t)) * direction
            dual = self._dual[safe].to(**like)  # (N, 2, 3)
            rel = (point - v0).T  # (N, 3)
            b1, b2 = (rel * dual[:, 0]).sum(1), (rel * dual[:, 1]).sum(1)
            # Embree chose in float32: a hit just outside its face belongs to the neighbour across
            # the edge opposite the most negative barycentric coordinate.
            weights = torch.stack([1 - b1 - b2, b1, b2]).detach()
            lowest, k = weights.min(0)
            across = self._neighbour[safe, k]
            move = hit & (lowest < 0) & (across >= 0)
            if attempt == REFINEMENTS or not bool(move.any()):
                break
            safe = torch.where(move, across, safe)
        corner = self._shading[safe].to(**like)  # (N, 3, 3): corner k's normal
        raw = ((1 - b1 - b2)[:, None] * corner[:, 0] + b1[:, None] * corner[:, 1] + b2[:, None] * corner[:, 2])
        length = raw.norm(dim=1, keepdim=True)
        normal = raw / length
        # d raw / dp = (n1 - n0) g1^T + (n2 - n0) g2^T; dN = (I - N N^T) d raw / |raw|.
        d_raw = (torch.einsum("ni,nj->nij", corner[:, 1] - corner[:, 0], dual[:, 0])
                 + torch.einsum("ni,nj->nij", corner[:, 2] - corner[:, 0], dual[:, 1]))
        project = torch.eye(3, **like) - torch.einsum("ni,nj->nij", normal, normal)
        gradient = torch.einsum("nij,njk->nik", project, d_raw) / length[:, :, None]
        element = torch.where(hit, self.face_element[safe], torch.full_like(face, -1))
        return ElementHits(torch.where(hit, face, torch.full_like(face, -1)), t, plane, normal.T,
                           gradient.permute(1, 2, 0), element)
