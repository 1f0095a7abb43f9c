"""A design given as a mesh of the planned glass (.stl, .obj, .ply), read as a height field.

The mesh is in millimetres in the frame of sfc-export's glass.stl (framework/files/mm_outputs.py):
the substrate's bottom at z = 0, its top at z = h, the substrate centred on x = y = 0. A vertical line
through each sample (x, y) of the grid crosses a closed height field twice (top and bottom); the
height there is the top's z - h. A line that misses the mesh, or crosses it more often (an overhang,
a second body), makes the file no height field: refused in one line.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["MESH_SUFFIXES", "heights_from_mesh"]

MESH_SUFFIXES = (".stl", ".obj", ".ply")


def heights_from_mesh(path: Path, resolution: int, half_width: float, thickness: float,
                      mm_per_unit: float) -> np.ndarray:
    """Heights (resolution, resolution), scene units, of the glass mesh at ``path`` (mm).

    Args:
        path: The mesh file. resolution: m. half_width, thickness: the substrate's W and h, scene
            units. mm_per_unit: mm per scene unit.
    """
    import trimesh

    if not path.is_file():
        raise FileNotFoundError(f"height_field.path {str(path)!r} does not exist; give the design as .npy, .png or "
                                "a glass mesh (.stl/.obj/.ply in mm)")
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as error:  # trimesh raises many types for unreadable files
        raise ValueError(f"height_field.path {str(path)!r} is not a readable mesh ({type(error).__name__}); export "
                         "the design as a binary or ASCII STL") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"height_field.path {str(path)!r} holds no triangles; export the design as a closed mesh")
    w, h = half_width * mm_per_unit, thickness * mm_per_unit
    s = np.linspace(-w, w, resolution) * (1.0 - 1e-4)  # just inside the walls
    x, y = np.meshgrid(s, s)  # [row, col] = [y, x]
    top_z = float(mesh.bounds[1, 2]) + 1.0
    origins = np.stack([x.ravel(), y.ravel(), np.full(x.size, top_z)], axis=1)
    directions = np.tile([0.0, 0.0, -1.0], (x.size, 1))
    locations, rays, _ = mesh.ray.intersects_location(origins, directions, multiple_hits=True)
    # hits through shared edges or vertices are found once per triangle: one crossing per distinct z
    crossings = np.unique(np.stack([rays, np.round(locations[:, 2], 6)], axis=1), axis=0)
    count = np.bincount(crossings[:, 0].astype(int), minlength=x.size)
    top = np.full(x.size, -np.inf)
    np.maximum.at(top, crossings[:, 0].astype(int), crossings[:, 1])
    for bad, what in ((count == 0, "misses the mesh"), (count > 2, "crosses the surface more than twice (an "
                                                                 "overhang or a second body)")):
        if bad.any():
            k = int(np.argmax(bad))
            raise ValueError(f"height_field.path {str(path)!r} is not a height field over the substrate: the vertical "
                             f"line at ({x.ravel()[k]:.2f}, {y.ravel()[k]:.2f}) mm {what}; give the glass in mm with "
                             f"the substrate's bottom at z = 0 over [-{w:g}, {w:g}] mm (as sfc-export writes it)")
    heights = (top.reshape(x.shape) - h) / mm_per_unit
    if heights.min() < -1e-6 * max(h, 1.0) / mm_per_unit:
        raise ValueError(f"height_field.path {str(path)!r}: the top lies {-heights.min() * mm_per_unit:.3g} mm below "
                         f"the substrate's top (z = {h:g} mm); check substrate.thickness or the mesh's frame")
    return np.clip(heights, 0.0, None)
