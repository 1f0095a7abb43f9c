"""Optical-element meshes: generated solids against their analytic volumes and normals, crease-split
shading normals, placement, and one-line refusals of bad meshes and layouts."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from operators.mesh_shapes import conic_sag, crease_normals, lens, lens_array, prism
from operators.optical_elements import check_layout, load_mesh, make_element


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


def _write(mesh: trimesh.Trimesh, path) -> str:
    mesh.export(path)
    return str(path)


@pytest.mark.parametrize("case, message", [
    ("missing", "does not exist"), ("text", "not a readable mesh|holds no triangles"), ("open", "is not closed"),
    ("inverted", "inward normals"), ("shape", "shape 'torus'"), ("key", "unknown key 'colour'"),
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
    from operators.mesh_intersect import _edge_neighbours

    faces = trimesh.creation.icosphere(subdivisions=1).faces
    neighbour = _edge_neighbours(faces)
    for f, corners in enumerate(faces):
        for k in range(3):
            edge = {int(corners[(k + 1) % 3]), int(corners[(k + 2) % 3])}
            other = faces[neighbour[f, k]]
            assert neighbour[f, k] != f and edge <= set(other.tolist()) and int(corners[k]) not in other
    open_mesh = faces[:-1]  # one face removed: its three neighbours now have an open edge
    assert int((_edge_neighbours(open_mesh) == -1).sum()) == 3
