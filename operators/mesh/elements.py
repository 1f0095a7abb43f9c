"""Optical elements in the light path: closed meshes with a placement, a material and shading
normals, from a file (OBJ / STL / PLY via trimesh) or a generator (operators/mesh/element_meshes.py).

An element's config (one entry of the list ``operator.elements``)::

    {name: top_lens, shape: lens, params: {radius: 1.085, thickness: 0.3, front_radius: 4.0, back_radius: 4.0},
     position: [0, 0, 1.15], rotation_deg: [0, 0, 0], material: {kind: fused_silica}, crease_angle_deg: 30}

``shape`` is ``lens``, ``prism``, ``lens_array`` or ``file`` (then ``path`` names the mesh file);
the rotation (degrees about x, then y, then z) and then the translation place the mesh. Shading
normals: a generated lens's exact ones, else crease-split averages (crease_angle_deg). Every mesh
is checked: finite vertices, closed, consistently wound, normals outward, and not intersecting
itself (no face crossing another; operators/mesh/crossings.py). :func:`check_layout` refuses
elements that overlap (a vertex of one inside another, or surfaces that cross; elements may touch)
or do not lie between the receiver and the light. Lengths (the position and the generators'
:data:`operators.mesh.element_meshes.Length` parameters) are in scene units or strings with a unit such as
"27 mm" (operators/lengths.py). Every config error is one line naming the key, e.g.
``operator.elements.top_lens.position``. Meshes of a million faces or more report a memory estimate
and their steps on stderr as they are built.
"""

from __future__ import annotations

import inspect
import math
import sys
import time
import typing
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from collections.abc import Callable, Mapping, Sequence

import numpy as np
import trimesh

from operators.lengths import DEFAULT_MM_PER_UNIT, scene_length
from operators.materials import DispersionCurve, material_from_config
from operators.mesh.crossings import mutual_crossings, self_crossings
from operators.mesh.element_meshes import crease_normals, lens, lens_array, prism
from operators.values import checked_number, checked_whole, is_number

__all__ = ["OpticalElement", "GENERATORS", "ELEMENT_KEYS", "LARGE_MESH_FACES", "MeshProgress", "load_mesh",
           "make_element", "make_elements", "check_layout", "PrintReachesElement"]


class PrintReachesElement(ValueError):
    """Heights whose print reaches into an optical element above the glass, or above where the
    light through the elements meets it: no mesh-scene operator renders them."""

GENERATORS: dict[str, Callable[..., trimesh.Trimesh]] = {"lens": lens, "prism": prism, "lens_array": lens_array}
ELEMENT_KEYS = ("name", "shape", "params", "path", "position", "rotation_deg", "material", "crease_angle_deg")
ELEMENTS_EXAMPLE = ("[{name: top_lens, shape: lens, params: {...}, position: [0, 0, 1.15]}] "
                    "(conf/operator/two_lenses.yaml)")
# Vertices per element tested for lying inside another (every vertex of small meshes).
OVERLAP_SAMPLES = 4096
# From this many faces on, building a mesh reports its memory estimate and its steps (MeshProgress).
LARGE_MESH_FACES = 1_000_000
# Peak memory of checking and building an element and the tracer's structures for it, per face:
# about 0.93 kB measured on 2 M-face meshes (a grid and a lens fan), rounded up.
BYTES_PER_FACE = 1_000
# Mesh files from this size on report that they are being read.
LARGE_MESH_FILE_BYTES = 16 << 20
# Generated elements (shape, params, placement, crease angle) kept built in this process, so that
# operators built again from the same config skip the checks and the shading normals; each build
# gets its own copy. Files are read again every time (they may change).
GENERATED_KEPT = 4
_GENERATED: dict[tuple, tuple[trimesh.Trimesh, np.ndarray]] = {}  # oldest first


class MeshProgress:
    """Lines on stderr for the slow steps of building a large mesh: quiet below
    :data:`LARGE_MESH_FACES` faces, else first the size (and with ``estimate`` the memory that
    building an element of that size takes), then each step as it starts and ends."""

    def __init__(self, what: str, faces: int, estimate: bool = True) -> None:
        self.what, self.active = what, faces >= LARGE_MESH_FACES
        if self.active:
            memory = f"; checking and building it takes about {faces * BYTES_PER_FACE / 1e9:.1f} GB of memory"
            self.say(f"{faces:,} faces{memory if estimate else ''}")

    def say(self, line: str) -> None:
        """One line about the mesh, at once."""
        print(f"{self.what}: {line}", file=sys.stderr, flush=True)

    @contextmanager
    def step(self, doing: str) -> Iterator[None]:
        """Say what is being done (a large mesh only), and when it is done, how long it took."""
        if not self.active:
            yield
            return
        start = time.perf_counter()
        self.say(f"{doing} ...")
        yield
        self.say(f"{doing}: done in {time.perf_counter() - start:.1f} s")


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


def load_mesh(path: str | Path, what: str | None = None) -> trimesh.Trimesh:
    """A triangle mesh from an OBJ / STL / PLY file (duplicate vertices merged), with one-line
    errors for a missing file, one that holds no mesh, or vertices that are not finite; a large
    file is announced on stderr as ``what`` (default: the path)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file {path} does not exist; check the element's path")
    size = path.stat().st_size
    if size >= LARGE_MESH_FILE_BYTES:
        print(f"{what or path}: reading {path} ({size / 1e6:.0f} MB) ...", file=sys.stderr, flush=True)
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as error:  # noqa: BLE001 - trimesh raises many kinds for unreadable files
        raise ValueError(
            f"{path} is not a readable mesh ({type(error).__name__}: {error}); use OBJ, STL or PLY"
        ) from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{path} holds no triangles; use an OBJ, STL or PLY triangle mesh")
    bad = ~np.isfinite(mesh.vertices).all(axis=1)
    used = bad[mesh.faces].any(axis=1)
    if used.any():
        raise ValueError(f"{path} has NaN or infinite vertex coordinates ({int(bad.sum())} of its {len(bad)} vertices, "
                         f"the first vertex {int(np.flatnonzero(bad)[0])}); fix the mesh or export it again")
    return mesh.process()


def _triple(value: Any, where: str, read: Callable[[Any, str], float], fix: str) -> tuple[float, float, float]:
    """Three values read by ``read`` from a list, else a ValueError naming ``where`` and ``fix``."""
    if not isinstance(value, Sequence) or isinstance(value, (str, bytes)) or len(value) != 3:
        raise ValueError(f"{where}={value!r} must be {fix}")
    x, y, z = (read(v, f"{where}[{i}]") for i, v in enumerate(value))
    if not all(math.isfinite(v) for v in (x, y, z)):
        raise ValueError(f"{where}={value!r} must be finite: {fix}")
    return x, y, z


def _generator_params(shape: str, params: Any, where: str, mm_per_unit: float) -> dict[str, Any]:
    """The keyword arguments of generator ``shape`` from config ``params`` (``where``): every key
    known, every required one given, lengths (:data:`operators.mesh.element_meshes.Length`) in scene units
    or with a unit, integers and numbers checked."""
    generator = GENERATORS[shape]
    signature = inspect.signature(generator).parameters
    hints = typing.get_type_hints(generator, include_extras=True)
    takes = ", ".join(signature)
    if params is None:
        params = {}
    if not isinstance(params, Mapping):
        raise ValueError(f"{where}={params!r} must be a mapping of the {shape}'s parameters: {takes}")
    for key in params:
        if key not in signature:
            raise ValueError(f"unknown key {where}.{key}; a {shape} takes: {takes}")
    for key, parameter in signature.items():
        if parameter.default is inspect.Parameter.empty and key not in params:
            raise ValueError(f"{where} needs {key} (a {shape} takes: {takes}); give e.g. {where}.{key}=...")
    values = {}
    for key, value in params.items():
        hint, name = hints[key], f"{where}.{key}"
        if typing.get_origin(hint) is typing.Annotated:
            values[key] = scene_length(value, mm_per_unit, name)
        elif hint is int:
            values[key] = checked_whole(value, name, must="must be an integer")
        else:
            values[key] = checked_number(value, name, must="must be a number")
    return values


def _is_name(name: Any) -> bool:
    """Whether ``name`` can name an element: a non-empty string or an int (not a bool)."""
    return (isinstance(name, str) or (isinstance(name, int) and is_number(name))) and str(name) != ""


def make_element(spec: Mapping[str, Any], base_dir: str | Path | None = None,
                 mm_per_unit: float = DEFAULT_MM_PER_UNIT, where: str | None = None) -> OpticalElement:
    """The element of config ``spec`` (module docstring), placed and checked; lengths given with a
    unit are converted at ``mm_per_unit`` mm per scene unit, and config errors name the keys under
    ``where`` (default ``operator.elements.<name>``)."""
    if not isinstance(spec, Mapping):
        raise ValueError(f"{where or 'an element'}={spec!r} must be a mapping with keys {', '.join(ELEMENT_KEYS)}")
    spec = dict(spec)
    name = spec.get("name", "element")
    if not _is_name(name):
        raise ValueError(f"{where or 'operator.elements'}.name={name!r} must be a string, e.g. top_lens")
    name = str(name)
    key = where or f"operator.elements.{name}"
    what = f"element {name}"
    unknown = [k for k in spec if k not in ELEMENT_KEYS]
    if unknown:
        raise ValueError(f"unknown key {key}.{unknown[0]}; an element takes: {', '.join(ELEMENT_KEYS)}")
    shape, path = spec.get("shape"), spec.get("path")
    if not isinstance(shape, str) or shape not in [*GENERATORS, "file"]:
        raise ValueError(f"unknown {key}.shape {shape!r}; use {', '.join([*GENERATORS, 'file'])}")
    position = _triple(spec.get("position", (0.0, 0.0, 0.0)), f"{key}.position",
                       lambda v, at: scene_length(v, mm_per_unit, at),
                       "[x, y, z] (scene units or strings such as '27 mm'), e.g. [0, 0, 1.15]")
    rotation = _triple(spec.get("rotation_deg", (0.0, 0.0, 0.0)), f"{key}.rotation_deg",
                       lambda v, at: checked_number(v, at, must="must be a number of degrees"),
                       "[x, y, z] in degrees, e.g. [0, 0, 45]")
    material = material_from_config(spec.get("material"), f"{key}.material")
    crease = checked_number(spec.get("crease_angle_deg", 30.0), f"{key}.crease_angle_deg",
                            must="must be a number of degrees", example="30")
    if not 0.0 <= crease < 180.0:
        raise ValueError(f"{key}.crease_angle_deg={crease:g} must lie in [0, 180), e.g. 30")
    if shape == "file":
        if not isinstance(path, str) or not path:
            raise ValueError(f"{key}.path={path!r} must be the path of an OBJ, STL or PLY mesh file (shape: file)")
        full = Path(path) if base_dir is None or Path(path).is_absolute() else Path(base_dir) / path
        mesh = load_mesh(full, what)
        what = f"{what} ({full})"
        mesh, normals = _placed(mesh, position, rotation, crease, what)
        return OpticalElement(name, mesh, normals, material)
    params = _generator_params(shape, spec.get("params"), f"{key}.params", mm_per_unit)
    built = (shape, repr(sorted(params.items())), tuple(position), tuple(rotation), crease)
    if built not in _GENERATED:
        try:
            mesh = GENERATORS[shape](**params)
        except ValueError as error:
            raise ValueError(f"{key}.params: {error}") from None
        _GENERATED[built] = _placed(mesh, position, rotation, crease, what)
        while len(_GENERATED) > GENERATED_KEPT:
            _GENERATED.pop(next(iter(_GENERATED)))
    mesh, normals = _GENERATED[built]
    return OpticalElement(name, mesh.copy(), normals.copy(), material)


def _placed(mesh: trimesh.Trimesh, position: Sequence[float], rotation: Sequence[float], crease: float,
            what: str) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The mesh checked (closed, not crossing itself) and placed, with its shading normals (F, 3, 3)."""
    progress = MeshProgress(what, len(mesh.faces))
    with progress.step("checking that it is closed"):
        _check_closed(mesh, what)
    with progress.step("checking that it does not cross itself"):
        _check_not_self_crossing(mesh, what)
    exact = mesh.metadata.get("corner_normals")
    placement = _placement(position, rotation)
    with progress.step("placing it and computing its shading normals"):
        mesh = mesh.copy()
        mesh.apply_transform(placement)
        normals = crease_normals(mesh, crease) if exact is None else exact @ placement[:3, :3].T
    return mesh, normals


def make_elements(specs: Any, base_dir: str | Path | None = None, mm_per_unit: float = DEFAULT_MM_PER_UNIT,
                  where: str = "operator.elements") -> list[OpticalElement]:
    """The elements of config list ``specs`` (:func:`make_element`; None: none), each named in
    errors as ``<where>.<name>`` (``<where>.<index>`` when it has no name); names must differ."""
    if specs is None:
        return []
    if not isinstance(specs, Sequence) or isinstance(specs, (str, bytes)):
        raise ValueError(f"{where}={specs!r} must be a list of elements, e.g. {where}={ELEMENTS_EXAMPLE}")
    names: set[str] = set()
    elements = []
    for index, spec in enumerate(specs):
        name = spec.get("name") if isinstance(spec, Mapping) else None
        named = _is_name(name)
        key = f"{where}.{name}" if named else f"{where}.{index}"
        if named and str(name) in names:
            raise ValueError(f"{key}: two elements are named {name}; give each element its own name")
        names.add(str(name))
        if isinstance(spec, Mapping) and name is None:
            spec = {**spec, "name": f"element{index}"}
        elements.append(make_element(spec, base_dir, mm_per_unit, key))
    return elements


def _check_closed(mesh: trimesh.Trimesh, what: str) -> None:
    if not mesh.is_watertight:
        open_edges = int(len(trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)))
        raise ValueError(f"{what} is not closed ({open_edges} edges with one face); an element must be a closed solid")
    if not mesh.is_winding_consistent:
        raise ValueError(
            f"{what} has faces wound inconsistently; fix their orientation (e.g. trimesh.repair.fix_winding)"
        )
    if not mesh.volume > 0:
        raise ValueError(f"{what} has inward normals (signed volume {mesh.volume:.4g}); flip its faces")


def _check_not_self_crossing(mesh: trimesh.Trimesh, what: str) -> None:
    crossings = self_crossings(mesh)
    if len(crossings):
        x, y, z = crossings.points[0]
        raise ValueError(f"{what} intersects itself ({len(crossings)} pairs of faces cross, the first at "
                         f"({x:.4g}, {y:.4g}, {z:.4g}) in the mesh's coordinates); make it one surface that does "
                         "not cross itself (e.g. a boolean union of its overlapping parts)")


def _placement(position: Sequence[float], rotation_deg: Sequence[float]) -> np.ndarray:
    """The 4 x 4 placement: the rotation (degrees about x, then y, then z), then the translation."""
    matrix = trimesh.transformations.euler_matrix(*np.radians(rotation_deg), axes="sxyz")
    matrix[:3, 3] = position
    return matrix


def _check_apart(a: OpticalElement, b: OpticalElement) -> None:
    """Refuse two elements that overlap: a vertex of one inside the other (ray parity), or their
    surfaces crossing (operators/mesh/crossings.py); touching is allowed."""
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
