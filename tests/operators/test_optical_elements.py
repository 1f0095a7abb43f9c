"""Optical-element meshes: generated solids against their analytic volumes and normals, crease-split
shading normals, placement, and one-line refusals of bad meshes and layouts (self-intersecting
meshes, elements whose surfaces cross)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from operators.mesh.crossings import self_crossings
from operators.mesh.element_meshes import conic_sag, crease_normals, height_field_solid, lens, lens_array, prism
from operators.mesh.elements import check_layout, make_element


def cap_volume(radius: float, height: float) -> float:
    return math.pi * height ** 2 * (3 * radius - height) / 3


def test_a_biconvex_lens_has_the_volume_of_its_caps_and_rim():
    mesh = lens(radius=1.0, thickness=0.3, front_radius=4.0, back_radius=6.0, rings=64, segments=256)
    sag_front, sag_back = conic_sag(np.array([1.0]), 4.0)[0], conic_sag(np.array([1.0]), 6.0)[0]
    expected = math.pi * (0.3 - sag_front - sag_back) + cap_volume(4.0, sag_front) + cap_volume(6.0, sag_back)
    assert mesh.is_watertight and mesh.volume == pytest.approx(expected, rel=2e-4)
    assert mesh.bounds[1, 2] == pytest.approx(0.15) and mesh.bounds[0, 2] == pytest.approx(-0.15)


def test_conic_sag_is_the_sphere_and_a_paraboloid_for_k_minus_one():
    r = np.linspace(0.0, 0.9, 7)
    np.testing.assert_allclose(conic_sag(r, 2.0), 2.0 - np.sqrt(4.0 - r ** 2), atol=1e-14)
    np.testing.assert_allclose(conic_sag(r, 2.0, conic=-1.0), r ** 2 / 4.0, atol=1e-14)
    with pytest.raises(ValueError, match="does not reach the aperture"):
        conic_sag(np.array([3.0]), 2.0)


def test_prism_and_lens_array_volumes():
    assert prism(1.299, 1.4).volume == pytest.approx(math.sqrt(3) / 4 * 1.299 ** 2 * 1.4, rel=1e-12)
    plate = lens_array(1.0, 0.1, 0.1, 0.25, 7, resolution=401)
    assert plate.is_watertight
    assert plate.volume == pytest.approx(4 * 0.1 + 49 * 2 / 3 * math.pi * 0.1 ** 3, rel=1e-3)
    assert plate.bounds[0, 2] == pytest.approx(-0.2, abs=1e-3)  # lenslet apexes


def test_crease_normals_are_smooth_on_a_face_and_split_at_edges():
    glass = lens(radius=1.0, thickness=0.3, front_radius=4.0, back_radius=4.0)
    normals = crease_normals(glass, 30.0)
    front = glass.face_normals[:, 2] > 0.5
    exact = glass.vertices[glass.faces] - np.array([0.0, 0.0, 0.15 - 4.0])  # the front sphere's centre
    exact /= np.linalg.norm(exact, axis=-1, keepdims=True)
    angle = np.degrees(np.arccos(np.clip((normals * exact).sum(-1), -1, 1)))[front]
    assert angle.max() < 0.25  # degrees, against the sphere's normal
    rim = np.abs(glass.face_normals[:, 2]) < 0.1
    assert np.abs(normals[rim][..., 2]).max() < 1e-12  # the rim is not bent toward the faces
    sharp = prism(1.0, 1.0)
    np.testing.assert_allclose(crease_normals(sharp, 30.0), np.repeat(sharp.face_normals[:, None], 3, 1), atol=1e-12)


def test_elements_are_placed_and_written(tmp_path):
    element = make_element({"name": "top", "shape": "lens", "position": [0.1, 0.0, 1.15], "rotation_deg": [0, 0, 45],
                            "params": {"radius": 1.085, "thickness": 0.3, "front_radius": 4.0, "back_radius": 4.0}})
    assert element.z_range == pytest.approx((1.0, 1.3))
    assert element.mesh.centroid[0] == pytest.approx(0.1, abs=1e-9)
    path = element.write(tmp_path / "top.stl")
    again = make_element({"name": "copy", "shape": "file", "path": str(path)})
    assert again.mesh.volume == pytest.approx(element.mesh.volume, rel=1e-6)


def test_a_generated_element_built_again_is_a_fresh_copy_of_the_same_element(monkeypatch):
    """Generated elements are kept built per process: a second build from the same config equals
    a build from scratch bit for bit, is its own copy (changing it changes no later build), and
    other parameters or placements build other elements."""
    from operators.mesh import elements

    monkeypatch.setattr(elements, "_GENERATED", {})
    spec = {"name": "top", "shape": "lens", "position": [0.1, 0.0, 1.15], "rotation_deg": [0, 0, 45],
            "params": {"radius": 1.0, "thickness": 0.3, "front_radius": 4.0, "back_radius": 4.0}}
    first = make_element(spec)
    first.mesh.vertices += 1.0  # the caller's copy; later builds must not see this
    first.normals[:] = 0.0
    second = make_element(spec)
    assert len(elements._GENERATED) == 1
    monkeypatch.setattr(elements, "_GENERATED", {})
    scratch = make_element(spec)
    assert np.array_equal(second.mesh.vertices, scratch.mesh.vertices)
    assert np.array_equal(second.mesh.faces, scratch.mesh.faces)
    assert np.array_equal(second.normals, scratch.normals)
    moved = make_element({**spec, "position": [0.1, 0.0, 1.25]})
    assert moved.z_range == pytest.approx((1.1, 1.4)) and scratch.z_range == pytest.approx((1.0, 1.3))
    thicker = make_element({**spec, "params": {**spec["params"], "thickness": 0.4}})
    assert thicker.z_range[1] - thicker.z_range[0] == pytest.approx(0.4)
    for k in range(elements.GENERATED_KEPT + 2):  # the kept elements stay few
        make_element({**spec, "position": [0.0, 0.0, 2.0 + k]})
    assert len(elements._GENERATED) == elements.GENERATED_KEPT


def _write(mesh: trimesh.Trimesh, path) -> str:
    mesh.export(path)
    return str(path)


@pytest.mark.parametrize("case, message", [
    ("missing", "does not exist"), ("text", "not a readable mesh|holds no triangles"), ("open", "is not closed"),
    ("inverted", "inward normals"), ("shape", "shape 'torus'"), ("key", "unknown key operator.elements.bad.colour"),
    ("thin lens", "lens faces cross inside the aperture"),
])
def test_bad_meshes_are_refused_in_one_line(tmp_path, case, message):
    box = trimesh.creation.box()
    specs = {
        "missing": {"shape": "file", "path": str(tmp_path / "none.obj")},
        "text": {"shape": "file", "path": str(tmp_path / "notes.obj")},
        "open": {"shape": "file", "path": _write(trimesh.Trimesh(box.vertices, box.faces[:-2], process=False),
                                                 tmp_path / "open.ply")},
        "inverted": {"shape": "file", "path": _write(trimesh.Trimesh(box.vertices, box.faces[:, ::-1], process=False),
                                                     tmp_path / "inverted.ply")},
        "shape": {"shape": "torus"},
        "key": {"shape": "prism", "params": {"side": 1, "length": 1}, "colour": "red"},
        "thin lens": {"shape": "lens", "params": {"radius": 1.0, "thickness": 0.2, "front_radius": 1.2,
                                                  "back_radius": 1.2}},
    }
    (tmp_path / "notes.obj").write_text("these are notes, not a mesh\n")
    with pytest.raises((ValueError, FileNotFoundError), match=message):
        make_element({"name": "bad", **specs[case]})


def test_layouts_that_overlap_or_leave_the_light_path_are_refused():
    def placed(name, z):
        return make_element({"name": name, "shape": "lens", "position": [0, 0, z],
                             "params": {"radius": 1.0, "thickness": 0.3, "front_radius": 4.0, "back_radius": 4.0}})

    check_layout([placed("a", 1.15), placed("b", -0.65)], light_z=10.0, receiver_z=-1.0)  # the two-lens layout
    with pytest.raises(ValueError, match="elements a and b overlap"):
        check_layout([placed("a", 1.15), placed("b", 1.25)], light_z=10.0, receiver_z=-1.0)
    with pytest.raises(ValueError, match="at or below the receiver"):
        check_layout([placed("a", -0.65)], light_z=10.0, receiver_z=-0.7)
    with pytest.raises(ValueError, match="at or above the light"):
        check_layout([placed("a", 9.9)], light_z=10.0, receiver_z=-1.0)


def test_each_face_knows_its_neighbour_across_the_edge_opposite_each_corner():
    from operators.mesh.intersect_reference import _edge_neighbours

    faces = trimesh.creation.icosphere(subdivisions=1).faces
    neighbour = _edge_neighbours(faces)
    for f, corners in enumerate(faces):
        for k in range(3):
            edge = {int(corners[(k + 1) % 3]), int(corners[(k + 2) % 3])}
            other = faces[neighbour[f, k]]
            assert neighbour[f, k] != f and edge <= set(other.tolist()) and int(corners[k]) not in other
    open_mesh = faces[:-1]  # one face removed: its three neighbours now have an open edge
    assert int((_edge_neighbours(open_mesh) == -1).sum()) == 3


def _box(low, high) -> trimesh.Trimesh:
    return trimesh.creation.box(bounds=[low, high])


def _bent_lens() -> tuple[trimesh.Trimesh, float]:
    """A closed lens mesh whose front face sags by twice its sphere's sag, so that it crosses the
    back face on the circle of radius r where 0.3 = 3 sag(r): the mesh and r."""
    mesh = lens(1.0, 0.3, 4.0, 4.0, rings=16, segments=32)
    vertices = mesh.vertices.copy()
    front = np.arange(len(vertices)) < len(vertices) // 2
    vertices[front, 2] = 0.15 - 2.0 * conic_sag(np.hypot(*vertices[front, :2].T), 4.0)
    radius = float(np.sqrt(0.1 * (2 * 4.0 - 0.1)))  # sag(r) = 0.1 on the sphere of radius 4
    return trimesh.Trimesh(vertices, mesh.faces, process=False), radius


@pytest.mark.parametrize("shape", ["two boxes", "bent lens"])
def test_a_closed_mesh_that_crosses_itself_is_refused_in_one_line(tmp_path, shape):
    mesh = (trimesh.util.concatenate([_box([0, 0, 0], [1, 1, 1]), _box([0.5, 0.3, 0.2], [1.5, 1.3, 1.2])])
            if shape == "two boxes" else _bent_lens()[0])
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0  # passes the older checks
    path = _write(mesh, tmp_path / "crossed.ply")
    with pytest.raises(ValueError, match=r"^element crossed \(.*crossed.ply\) intersects itself \(\d+ pairs of faces "
                                         r"cross, the first at \(.*\) in the mesh's coordinates\); make it one "
                                         r"surface that does not cross itself") as refused:
        make_element({"name": "crossed", "shape": "file", "path": path})
    assert "\n" not in str(refused.value)


def test_self_crossings_pair_faces_of_the_two_overlapping_parts_where_they_cross():
    first, second = _box([0, 0, 0], [1, 1, 1]), _box([0.5, 0.3, 0.2], [1.5, 1.3, 1.2])
    crossings = self_crossings(trimesh.util.concatenate([first, second]))
    assert len(crossings) > 0
    assert np.all(crossings.pairs[:, 0] < 12) and np.all(crossings.pairs[:, 1] >= 12)  # never two faces of one box
    low, high = np.array([0.5, 0.3, 0.2]) - 1e-5, np.array([1.0, 1.0, 1.0]) + 1e-5
    assert np.all((crossings.points >= low) & (crossings.points <= high))  # where the boxes overlap
    bent, radius = _bent_lens()
    points = self_crossings(bent).points
    assert len(points) > 0
    np.testing.assert_allclose(np.hypot(points[:, 0], points[:, 1]), radius, atol=0.02)  # the faceted faces
    np.testing.assert_allclose(points[:, 2], -0.15 + 0.1, atol=0.01)  # on the back face, z = -t/2 + sag(r)


GENERATED = {
    "biconvex lens": lambda: lens(1.08, 0.3, 4.0, 4.0),
    "meniscus": lambda: lens(1.0, 0.15, -2.125, 1.817),
    "conic lens": lambda: lens(1.0, 0.4, 2.0, -5.0, front_conic=-1.5, back_conic=0.8),
    "lens with a rim 1e-4 thick": lambda: lens(1.0, 2 * float(conic_sag(np.array([1.0]), 4.0)[0]) + 1e-4, 4.0, 4.0),
    "prism": lambda: prism(1.299, 1.4),
    # One surface: the lenslets are the plate's underside height field, not solids touching it.
    "lens array": lambda: lens_array(1.0, 0.1, 0.1, 0.25, 7, resolution=161),
    "height-field solid": lambda: height_field_solid(lambda x, y: 0.2 + 0.05 * np.sin(7 * x) * np.cos(5 * y),
                                                     lambda x, y: -0.1 * x ** 2, 1.0, 101),
}


@pytest.mark.parametrize("name", list(GENERATED))
def test_generated_meshes_do_not_cross_themselves_wherever_they_are_placed(name):
    mesh = GENERATED[name]()
    assert len(self_crossings(mesh)) == 0
    placement = trimesh.transformations.euler_matrix(0.3, 0.7, 1.1)
    placement[:3, 3] = [1000.0, -50.0, 3.0]  # far from the origin, where float32 keeps 4 digits fewer
    assert len(self_crossings(mesh.apply_transform(placement))) == 0


@pytest.mark.parametrize("operator", ["two_lenses", "prism_lens_array"])
def test_the_papers_scenes_pass_every_check(operator):
    from hydra import compose, initialize_config_dir

    conf = Path(__file__).resolve().parents[2] / "conf"
    with initialize_config_dir(config_dir=str(conf), version_base=None):
        cfg = compose("simulate", overrides=[f"operator={operator}"])
    elements = [make_element(dict(spec)) for spec in cfg.operator.elements]  # each checked for self-crossings
    assert all(len(self_crossings(element.mesh)) == 0 for element in elements)
    check_layout(elements, light_z=cfg.light.position[2], receiver_z=cfg.receiver.z)


def _file_element(tmp_path, name: str, mesh: trimesh.Trimesh, position=(0.0, 0.0, 0.0)):
    return make_element({"name": name, "shape": "file", "path": _write(mesh, tmp_path / f"{name}.ply"),
                         "position": list(position)})


def test_elements_whose_surfaces_cross_with_no_vertex_inside_the_other_are_refused(tmp_path):
    a = _file_element(tmp_path, "a", _box([-2.0, -0.4, -0.5], [2.0, 0.4, 0.5]))
    b = _file_element(tmp_path, "b", _box([-0.3, -2.0, -0.2], [0.3, 2.0, 0.2]))  # a plus sign seen from above
    assert not a.mesh.contains(b.mesh.vertices).any() and not b.mesh.contains(a.mesh.vertices).any()
    with pytest.raises(ValueError, match=r"^elements a and b overlap \(their surfaces cross at \(.*\)\); "
                                         r"move them apart$"):
        check_layout([a, b], light_z=10.0, receiver_z=-1.0)


def test_elements_and_parts_of_a_mesh_may_touch_without_crossing(tmp_path):
    corners = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [1.0, 1.0], [1.0, 2.0], [0.0, 2.0]])
    ell = trimesh.creation.extrude_triangulation(corners, np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]]), 1.0)
    corner = _box([1.0, 1.0, 0.0], [1.4, 1.7, 0.5])  # in the L's inner corner, against both of its walls
    elements = [_file_element(tmp_path, "ell", ell), _file_element(tmp_path, "corner", corner)]
    assert np.all(elements[1].mesh.bounds[0] < elements[0].mesh.bounds[1])  # boxes overlap: surfaces are tested
    check_layout(elements, light_z=10.0, receiver_z=-1.0)
    pushed = _file_element(tmp_path, "pushed", corner, position=(-0.01, 0.0, 0.0))
    with pytest.raises(ValueError, match="elements ell and pushed overlap"):
        check_layout([elements[0], pushed], light_z=10.0, receiver_z=-1.0)
    touching = trimesh.util.concatenate([_box([0, 0, 0], [1, 1, 1]), _box([1.0, 0.3, 0.2], [2.0, 1.3, 1.2])])
    assert len(_file_element(tmp_path, "touching", touching).mesh.faces) == 24  # one mesh, face to face: accepted
