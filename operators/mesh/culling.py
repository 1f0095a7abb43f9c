"""Faces with every element behind their plane: a photon that leaves such a face outward, at a
steep enough angle, meets no element again, so the kernels ask Embree nothing more for it (the
ray that would find nothing below the lowest lens before the receiver).

Why the angle: Embree traces the float32 copy of the faces, whose corners lie up to about 1e-7
(scene units, at coordinates of order 1) off the exact ones, from START_OFFSET along the ray. A ray
leaving the plane with cos >= CLEAR_COS is farther than that from it beyond MIN_FACE_DISTANCE,
the nearest face hit the kernels accept, so no face it could be told of is one they would take.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from scipy.spatial import ConvexHull

from operators.kernels.numba_settings import jit_parallel
from operators.mesh.locality import morton_order

__all__ = ["CLEAR_COS", "clear_faces"]

# Least cosine between a photon leaving a clear face and the face's normal for the skip.
CLEAR_COS = 0.5
# Vertices at most this far (scene units) in front of a face's plane count as behind it (rounding).
TOLERANCE = 1e-9
# Vertices per bounding sphere of the search.
CLUSTER = 64


def clear_faces(vertices: np.ndarray, v0: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """Whether each face (corner v0 (F, 3), unit outward normal ``plane`` (F, 3)) has every one of
    ``vertices`` (V, 3), all elements' corners, behind its plane: (F,) bool. Only the corners of
    their convex hull can lie farthest in front of a plane, so only those are tried."""
    corners = vertices[ConvexHull(vertices).vertices]
    points = np.ascontiguousarray(corners[morton_order(corners)])
    count = (len(points) + CLUSTER - 1) // CLUSTER
    centres, radii = np.empty((count, 3)), np.empty(count)
    for k in range(count):
        group = points[k * CLUSTER:(k + 1) * CLUSTER]
        centres[k] = group.mean(axis=0)
        radii[k] = np.sqrt(((group - centres[k]) ** 2).sum(axis=1).max())
    out = np.empty(len(v0), dtype=np.bool_)
    _clear(points, centres, radii, v0, plane, out)
    return out


@jit_parallel
def _clear(points, centres, radii, v0, plane, out) -> None:
    """out[f]: no point lies more than TOLERANCE in front of face f's plane; groups of CLUSTER
    points (Morton order) whose bounding sphere lies behind it are passed over."""
    for f in nb.prange(v0.shape[0]):
        nx, ny, nz = plane[f, 0], plane[f, 1], plane[f, 2]
        limit = v0[f, 0] * nx + v0[f, 1] * ny + v0[f, 2] * nz + TOLERANCE
        clear = True
        for k in range(centres.shape[0]):
            if centres[k, 0] * nx + centres[k, 1] * ny + centres[k, 2] * nz + radii[k] <= limit:
                continue
            for j in range(k * CLUSTER, min((k + 1) * CLUSTER, points.shape[0])):
                if points[j, 0] * nx + points[j, 1] * ny + points[j, 2] * nz > limit:
                    clear = False
                    break
            if not clear:
                break
        out[f] = clear
