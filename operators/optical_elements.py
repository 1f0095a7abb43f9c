"""Optical elements in the light path: closed meshes with a placement, a material and shading
normals, from a file (OBJ / STL / PLY via trimesh) or a generator (operators/mesh_shapes.py).

An element's config::

    {name: top_lens, shape: lens, params: {radius: 1.085, thickness: 0.3, front_radius: 4.0, back_radius: 4.0},
     position: [0, 0, 1.15], rotation_deg: [0, 0, 0], material: {kind: fused_silica}, crease_angle_deg: 30}

``shape`` is ``lens``, ``prism``, ``lens_array`` or ``file`` (then ``path`` names the mesh file);
the rotation (degrees about x, then y, then z) and then the translation place the mesh. Shading
normals: a generated lens's exact ones, else crease-split averages (crease_angle_deg). Every mesh
is checked: closed, consistently wound, normals outward, and not intersecting itself (no face
crossing another; operators/mesh_crossings.py). :func:`check_layout` refuses elements that overlap
(a vertex of one inside another, or surfaces that cross; elements may touch) or do not lie between
the receiver and the light. Lengths in scene units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import trimesh

from operators.materials import DispersionCurve, make_material
from operators.mesh_crossings import mutual_crossings, self_crossings
from operators.mesh_shapes import crease_normals, lens, lens_array, prism

__all__ = ["OpticalElement", "GENERATORS", "load_mesh", "make_element", "check_layout"]

GENERATORS = {"lens": lens, "prism": prism, "lens_array": lens_array}
# Vertices per element tested for lying inside another (every vertex of small meshes).
OVERLAP_SAMPLES = 4096


@dataclass(frozen=True)
class OpticalElement:
    """A placed, checked element.

    Attributes:
        name: What the config calls it.
        mesh: The closed triangle mesh in scene coordinates (outward normals).
        normals: Shading normals (F, 3, 3) at the corners of every face (crease-split).
        material: Its dispersion curve.
    """

    name: str
    mesh: trimesh.Trimesh
    normals: np.ndarray
    material: DispersionCurve

    @property
    def z_range(self) -> tuple[float, float]:
        """Lowest and highest z of the element."""
        return float(self.mesh.bounds[0, 2]), float(self.mesh.bounds[1, 2])

    def write(self, path: str | Path) -> Path:
        """Write the placed mesh (OBJ, STL or PLY by the suffix)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        self.mesh.export(path)
        return path


def load_mesh(path: str | Path) -> trimesh.Trimesh:
    """A triangle mesh from an OBJ / STL / PLY file, with one-line errors for a missing file or one
    that holds no mesh."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file {path} does not exist; check the element's path")
    try:
        mesh = trimesh.load(path, force="mesh", process=True)
    except Exception as error:  # noqa: BLE001 - trimesh raises many kinds for unreadable files
        raise ValueError(f"{path} is not a readable mesh ({type(error).__name__}: {error}); use OBJ, STL or PLY") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{path} holds no triangles; use an OBJ, STL or PLY triangle mesh")
    return mesh


def _check_closed(mesh: trimesh.Trimesh, what: str) -> None:
    if not mesh.is_watertight:
        open_edges = int(len(trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)))
        raise ValueError(f"{what} is not closed ({open_edges} edges with one face); an element must be a closed solid")
    if not mesh.is_winding_consistent:
        raise ValueError(f"{what} has faces wound inconsistently; fix their orientation (e.g. trimesh.repair.fix_winding)")
    if not mesh.volume > 0:
        raise ValueError(f"{what} has inward normals (signed volume {mesh.volume:.4g}); flip its faces")


def _check_not_self_crossing(mesh: trimesh.Trimesh, what: str) -> None:
    crossings = self_crossings(mesh)
    if len(crossings):
        x, y, z = crossings.points[0]
        raise ValueError(f"{what} intersects itself ({len(crossings)} pairs of faces cross, the first at "
                         f"({x:.4g}, {y:.4g}, {z:.4g}) in the mesh's coordinates); make it one surface that does "
                         "not cross itself (e.g. a boolean union of its overlapping parts)")


def _placement(position: Sequence[float], rotation_deg: Sequence[float], what: str) -> np.ndarray:
    if len(position) != 3 or len(rotation_deg) != 3:
        raise ValueError(f"{what}: position and rotation_deg must have three entries, got {position!r}, {rotation_deg!r}")
    values = [float(v) for v in (*position, *rotation_deg)]
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{what}: position and rotation must be finite, got {position!r}, {rotation_deg!r}")
    matrix = trimesh.transformations.euler_matrix(*np.radians(values[3:]), axes="sxyz")
    matrix[:3, 3] = values[:3]
    return matrix


def make_element(spec: Mapping[str, Any], base_dir: str | Path | None = None) -> OpticalElement:
    """The element of config ``spec`` (module docstring), placed and checked."""
    spec = dict(spec)
    name = str(spec.pop("name", "element"))
    what = f"element {name}"
    shape = spec.pop("shape", None)
    params = dict(spec.pop("params", None) or {})
    path = spec.pop("path", None)
    position = spec.pop("position", (0.0, 0.0, 0.0))
    rotation = spec.pop("rotation_deg", (0.0, 0.0, 0.0))
    material = make_material(dict(spec.pop("material", None) or {"kind": "fused_silica"}))
    crease = float(spec.pop("crease_angle_deg", 30.0))
    if spec:
        raise ValueError(f"unknown key {next(iter(spec))!r} of {what}; keys: name, shape, params, path, position, "
                         "rotation_deg, material, crease_angle_deg")
    if shape == "file":
        if not path:
            raise ValueError(f"{what} has shape: file but no path")
        full = Path(path) if base_dir is None or Path(path).is_absolute() else Path(base_dir) / path
        mesh = load_mesh(full)
        what = f"{what} ({full})"
    elif shape in GENERATORS:
        try:
            mesh = GENERATORS[shape](**params)
        except TypeError as error:
            raise ValueError(f"{what}: {error}") from None
    else:
        raise ValueError(f"{what} has shape {shape!r}; use {', '.join([*GENERATORS, 'file'])}")
    _check_closed(mesh, what)
    _check_not_self_crossing(mesh, what)
    exact = mesh.metadata.get("corner_normals")
    placement = _placement(position, rotation, what)
    mesh = mesh.copy()
    mesh.apply_transform(placement)
    normals = crease_normals(mesh, crease) if exact is None else exact @ placement[:3, :3].T
    return OpticalElement(name, mesh, normals, material)


def _check_apart(a: OpticalElement, b: OpticalElement) -> None:
    """Refuse two elements that overlap: a vertex of one inside the other (ray parity), or their
    surfaces crossing (operators/mesh_crossings.py); touching is allowed."""
    if np.any(a.mesh.bounds[1] <= b.mesh.bounds[0]) or np.any(b.mesh.bounds[1] <= a.mesh.bounds[0]):
        return
    for inner, outer in ((a, b), (b, a)):
        step = max(1, len(inner.mesh.vertices) // OVERLAP_SAMPLES)
        if np.any(outer.mesh.contains(inner.mesh.vertices[::step])):
            raise ValueError(f"elements {a.name} and {b.name} overlap; move them apart")
    crossings = mutual_crossings(a.mesh, b.mesh)
    if len(crossings):
        x, y, z = crossings.points[0]
        raise ValueError(f"elements {a.name} and {b.name} overlap (their surfaces cross at ({x:.4g}, {y:.4g}, "
                         f"{z:.4g})); move them apart")


def check_layout(elements: Sequence[OpticalElement], light_z: float, receiver_z: float) -> None:
    """Refuse elements that reach the light or the receiver, or that overlap one another (a vertex
    of one inside the other, or surfaces that cross; elements may touch)."""
    for element in elements:
        low, high = element.z_range
        if high >= light_z:
            raise ValueError(f"element {element.name} reaches z={high:.4g}, at or above the light (z={light_z}); "
                             "move it down")
        if low <= receiver_z:
            raise ValueError(f"element {element.name} reaches z={low:.4g}, at or below the receiver "
                             f"(z={receiver_z}); move it up or lower the receiver")
    for i, a in enumerate(elements):
        for b in elements[i + 1:]:
            _check_apart(a, b)
