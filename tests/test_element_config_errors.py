"""Optical elements in the operator config: lengths in mm, every bad value refused in one line that
names its key (or the mesh file), and large meshes reported as they are built."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh

import operators.mesh.element_meshes as element_meshes
import operators.mesh.elements as optical_elements
from framework.scene.scene_config import build_operator, build_scene
from operators.mesh.element_meshes import crease_normals, lens, prism
from operators.mesh.elements import load_mesh, make_element, make_elements

LENS = {"name": "top_lens", "shape": "lens", "position": [0.0, 0.0, 1.15],
        "params": {"radius": 1.08, "thickness": 0.3, "front_radius": 4.0, "back_radius": 4.0, "rings": 4,
                   "segments": 16}}


def config(elements: Any, **operator: Any) -> dict[str, Any]:
    """A scene config with the mesh-scene operator (torch tracer: nothing to compile) and ``elements``."""
    return {"light": {"position": [0, 0, 10]}, "substrate": {"thickness": 0.1, "half_width": 1.0},
            "receiver": {"z": -1.0, "resolution": 8}, "photons": 1000, "units": {"mm_per_unit": 25.0},
            "operator": {"name": "mesh_scene", "native": False, "elements": elements, **operator}}


def lens_with(path: str, value: Any) -> dict[str, Any]:
    """The lens with the value at the dotted ``path`` (e.g. params.radius) replaced (None: removed)."""
    spec = copy.deepcopy(LENS)
    *parents, key = path.split(".")
    node = spec
    for parent in parents:
        node = node[parent]
    if value is None:
        del node[key]
    else:
        node[key] = value
    return spec


def one_line(error: pytest.ExceptionInfo) -> str:
    message = str(error.value)
    assert "\n" not in message and message
    return message


def test_lengths_in_mm_are_converted_with_the_runs_mm_per_unit() -> None:
    in_mm = lens_with("position", ["0 mm", 0.0, "28.75mm"])
    in_mm["params"] = {**in_mm["params"], "radius": "27 mm", "thickness": "7.5mm", "front_radius": "10 cm"}
    cfg = config([in_mm], aperture_half_width="27 mm")
    operator = build_operator(cfg, build_scene(cfg))
    reference = make_element(LENS)
    np.testing.assert_allclose(operator.elements[0].mesh.vertices, reference.mesh.vertices, atol=1e-12)
    assert operator.settings.aperture_half_width == pytest.approx(1.08)
    cfg["units"] = {"mm_per_unit": 20.0}  # the same lengths in mm on a shorter scene unit
    in_mm["params"]["radius"] = 1.08
    assert build_operator(cfg, build_scene(cfg)).elements[0].z_range[1] == pytest.approx(28.75 / 20 + 7.5 / 40)


@pytest.mark.parametrize("elements, message", [
    ([lens_with("position", 1.15)], "operator.elements.top_lens.position=1.15 must be [x, y, z] (scene units or "
                                    "strings such as '27 mm'), e.g. [0, 0, 1.15]"),
    ([lens_with("position", [0, 0, "abc"])], "operator.elements.top_lens.position[2]='abc' must be a number"),
    ([lens_with("position", [0, 0, float("nan")])], "operator.elements.top_lens.position=[0, 0, nan] must be finite"),
    (5, "operator.elements=5 must be a list of elements, e.g. operator.elements=[{name: top_lens, shape: lens"),
    ({"top_lens": LENS}, "operator.elements={'top_lens': "),
    ([5], "operator.elements.0=5 must be a mapping with keys name, shape, params, path, position"),
    ([lens_with("params.radius", True)], "operator.elements.top_lens.params.radius=True must be a number (scene "
                                         "units) or a string such as '2.5 mm'"),
    ([lens_with("params.radius", "27 inch")], "operator.elements.top_lens.params.radius='27 inch' must be a number"),
    ([lens_with("params.rings", 2.5)], "operator.elements.top_lens.params.rings=2.5 must be an integer"),
    ([lens_with("params.segments", "abc")], "operator.elements.top_lens.params.segments='abc' must be an integer"),
    ([lens_with("params.front_conic", "-1 mm")], "operator.elements.top_lens.params.front_conic='-1 mm' must be a "
                                                 "number"),
    ([lens_with("params.foo", 1)], "unknown key operator.elements.top_lens.params.foo; a lens takes: radius, "
                                   "thickness, front_radius"),
    ([lens_with("params.thickness", None)], "operator.elements.top_lens.params needs thickness (a lens takes: "),
    ([lens_with("params", 5)], "operator.elements.top_lens.params=5 must be a mapping of the lens's parameters"),
    ([lens_with("params.front_radius", 0.5)], "operator.elements.top_lens.params: a face of radius 0.5"),
    ([lens_with("rotation_deg", 5)], "operator.elements.top_lens.rotation_deg=5 must be [x, y, z] in degrees"),
    ([lens_with("rotation_deg", [0, 0, "x"])], "operator.elements.top_lens.rotation_deg[2]='x' must be a number"),
    ([lens_with("material", 5)], "operator.elements.top_lens.material=5 must be a mapping, e.g. {kind: fused_silica}"),
    ([lens_with("material", {"kind": "glass"})], "unknown operator.elements.top_lens.material.kind 'glass'"),
    ([lens_with("material", {"kind": "constant", "n": "abc"})], "operator.elements.top_lens.material.n='abc' must be "
                                                                "a number"),
    ([lens_with("material", {"kind": "sellmeier", "b": 1, "c": [1]})], "operator.elements.top_lens.material.b=1 "
                                                                       "must be a list of numbers"),
    ([lens_with("crease_angle_deg", "abc")], "operator.elements.top_lens.crease_angle_deg='abc' must be a number"),
    ([lens_with("crease_angle_deg", 200)], "operator.elements.top_lens.crease_angle_deg=200 must lie in [0, 180)"),
    ([lens_with("shape", "torus")], "unknown operator.elements.top_lens.shape 'torus'; use lens, prism, lens_array"),
    ([lens_with("colour", "red")], "unknown key operator.elements.top_lens.colour; an element takes: name, shape"),
    ([lens_with("shape", "file")], "operator.elements.top_lens.path=None must be the path of an OBJ, STL or PLY"),
    ([lens_with("name", [1])], "operator.elements.0.name=[1] must be a string"),
    ([LENS, LENS], "operator.elements.top_lens: two elements are named top_lens; give each element its own name"),
])
def test_bad_elements_are_refused_in_one_line_naming_the_key(elements: Any, message: str) -> None:
    cfg = config(elements)
    with pytest.raises(ValueError) as refused:
        build_operator(cfg, build_scene(cfg))
    assert one_line(refused).startswith(message)


def test_an_element_without_a_name_is_named_by_its_index() -> None:
    with pytest.raises(ValueError) as refused:
        make_elements([LENS, lens_with("name", None) | {"position": 1.0}])
    assert one_line(refused).startswith("operator.elements.1.position=1.0 must be [x, y, z]")


def test_a_bad_aperture_length_names_its_key() -> None:
    cfg = config([LENS], aperture_half_width="wide")
    with pytest.raises(ValueError) as refused:
        build_operator(cfg, build_scene(cfg))
    assert one_line(refused).startswith("operator.aperture_half_width='wide' must be a number (scene units)")


@pytest.mark.parametrize("suffix", ["ply", "stl", "obj"])
def test_a_mesh_file_with_nan_vertices_is_refused_by_name(tmp_path: Path, suffix: str) -> None:
    box = trimesh.creation.box()
    vertices = box.vertices.copy()
    vertices[0, 1] = np.nan
    path = tmp_path / f"nan.{suffix}"
    trimesh.Trimesh(vertices, box.faces, process=False).export(path)
    with pytest.raises(ValueError) as refused:
        make_elements([{"name": "box", "shape": "file", "path": str(path), "position": [0, 0, 1]}])
    assert one_line(refused).startswith(f"{path} has NaN or infinite vertex coordinates (")
    assert "fix the mesh or export it again" in str(refused.value)


def test_a_large_mesh_reports_its_memory_and_steps_and_a_small_one_nothing(tmp_path: Path, capsys,
                                                                           monkeypatch) -> None:
    path = tmp_path / "prism.ply"
    prism(1.0, 1.0).export(path)
    spec = {"name": "p", "shape": "file", "path": str(path), "position": [0, 0, 1]}
    make_element(spec)
    assert capsys.readouterr().err == ""  # below LARGE_MESH_FACES and LARGE_MESH_FILE_BYTES: quiet
    monkeypatch.setattr(optical_elements, "LARGE_MESH_FACES", 8)  # the prism's faces count as large
    monkeypatch.setattr(optical_elements, "LARGE_MESH_FILE_BYTES", 0)
    make_element(spec)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == f"element p: reading {path} (0 MB) ..."
    assert lines[1].startswith(f"element p ({path}): 8 faces; checking and building it takes about ")
    assert lines[1].endswith(" GB of memory")
    steps = ["checking that it is closed", "checking that it does not cross itself",
             "placing it and computing its shading normals"]
    assert [line.split(": ", 1)[1] for line in lines[2::2]] == [f"{step} ..." for step in steps]
    assert all(line.split(": ", 1)[1].startswith(f"{step}: done in ") for line, step in zip(lines[3::2], steps))


def test_crease_normals_in_small_blocks_equal_one_block(monkeypatch) -> None:
    fan = lens(1.0, 0.3, 4.0, 4.0, rings=3, segments=64)  # 64 faces meet at each apex
    box = trimesh.creation.box()
    whole = [crease_normals(mesh, angle) for mesh in (fan, box) for angle in (0.0, 30.0, 90.0)]
    monkeypatch.setattr(element_meshes, "CREASE_PAIRS_PER_BLOCK", 7)  # fewer pairs than one apex corner has
    blocks = [crease_normals(mesh, angle) for mesh in (fan, box) for angle in (0.0, 30.0, 90.0)]
    for a, b in zip(whole, blocks):
        np.testing.assert_allclose(a, b, atol=1e-14)
    np.testing.assert_allclose(whole[3], np.repeat(box.face_normals[:, None], 3, 1), atol=1e-12)


def test_load_mesh_still_merges_the_vertices_of_an_stl(tmp_path: Path) -> None:
    path = tmp_path / "box.stl"
    trimesh.creation.box().export(path)
    mesh = load_mesh(path)
    assert len(mesh.vertices) == 8 and mesh.is_watertight
