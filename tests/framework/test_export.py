"""Millimetre outputs (framework/files/mm_outputs.py): the glass mesh against analytic and trapezoid volumes,
mesh files read back, the 16-bit PNG round trip, hand-computed deviation metrics, bad inputs."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh
from PIL import Image

from framework.files.mm_outputs import (
    MESH_FORMATS,
    PRINTED,
    deviation_report,
    export_outputs,
    glass_mesh,
    read_height_png,
    write_height_png,
)

H, W, MM = 0.1, 1.0, 25.0  # substrate thickness and half width (scene units), mm per scene unit


def samples(m: int, w: float = W) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The grid's coordinates s (m,) and x, y (m, m), [row, col] = [y, x]."""
    s = np.linspace(-w, w, m)
    x, y = np.meshgrid(s, s)
    return s, x, y


def paraboloid_cap(m: int, radius: float = 0.6, height: float = 0.05) -> np.ndarray:
    """d = height (1 - r^2 / radius^2) inside the radius, 0 outside; volume pi radius^2 height / 2."""
    _, x, y = samples(m)
    return np.clip(height * (1.0 - (x ** 2 + y ** 2) / radius ** 2), 0.0, None)


def trapezoid_volume_mm3(d: np.ndarray, w: float, h: float, mm: float) -> float:
    s = np.linspace(-w, w, d.shape[0])
    return ((2 * w) ** 2 * h + float(np.trapezoid(np.trapezoid(d, s, axis=1), s))) * mm ** 3


def test_paraboloid_mesh_is_closed_outward_and_has_the_trapezoid_and_analytic_volume():
    d = paraboloid_cap(81)
    mesh = glass_mesh(d, W, H, MM)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert len(mesh.faces) == 4 * 80 ** 2 + 3 * 4 * 80  # top, walls, floor fan
    assert mesh.volume == pytest.approx(trapezoid_volume_mm3(d, W, H, MM), rel=1e-12)
    printed = mesh.volume - (2 * W) ** 2 * H * MM ** 3  # the cap alone: pi r^2 height / 2
    assert printed == pytest.approx(math.pi * 0.6 ** 2 * 0.05 / 2 * MM ** 3, rel=1e-3)
    np.testing.assert_allclose(mesh.bounds, [[-W * MM, -W * MM, 0.0], [W * MM, W * MM, (H + d.max()) * MM]],
                               rtol=0, atol=1e-12)


def test_tilted_plane_has_its_exact_volume_and_rises_towards_plus_x_and_plus_y():
    w, h, mm = 1.3, 0.05, 20.0
    s, x, y = samples(17, w)
    for d, axis in ((0.03 + 0.02 * x, 0), (0.03 + 0.02 * y, 1)):  # volume (2 w)^2 (h + 0.03) exactly
        mesh = glass_mesh(d, w, h, mm)
        assert mesh.is_watertight and mesh.is_winding_consistent
        assert mesh.volume == pytest.approx((2 * w) ** 2 * (h + 0.03) * mm ** 3, rel=1e-12)
        highest = mesh.vertices[mesh.vertices[:, 2] > (h + 0.03 + 0.02 * w - 1e-9) * mm]
        np.testing.assert_allclose(highest[:, axis], w * mm)  # the top edge lies at x = +w, then y = +w


def test_box_bump_on_a_coarse_grid_has_the_hand_computed_volume():
    d = np.zeros((5, 5))
    d[:3, :3] = 0.02  # in the corner: trapezoid weights 1/4 + 4 * 1/2 + 4 * 1 on cells of area 0.25
    mesh = glass_mesh(d, W, H, MM)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx((4 * H + 0.02 * 6.25 * 0.25) * MM ** 3, rel=1e-12)


def test_written_meshes_read_back_closed_with_the_same_volume(tmp_path):
    d = paraboloid_cap(48)
    result = export_outputs(tmp_path, d, W, H, MM, formats=MESH_FORMATS)
    assert result["deviation"] == {}
    assert [p.name for p in result["files"]] == ["height_field_mm.npy", "height_field_mm.png", "glass.stl",
                                                 "glass.obj", "glass.ply"]
    expected = trapezoid_volume_mm3(d, W, H, MM)
    for fmt in MESH_FORMATS:
        mesh = trimesh.load(tmp_path / f"glass.{fmt}")
        assert mesh.is_watertight and mesh.is_winding_consistent, fmt
        assert mesh.volume == pytest.approx(expected, rel=1e-8), fmt  # STL stores float32 coordinates
    np.testing.assert_array_equal(np.load(tmp_path / "height_field_mm.npy"), d * MM)
    assert not (tmp_path / "deviation.json").exists()


def test_png_round_trip_is_within_half_a_count_with_plus_y_on_top(tmp_path):
    rng = np.random.default_rng(3)
    _, _, y = samples(40)
    d_mm = 1.5 * (y + 1.0) + rng.normal(0.0, 0.2, y.shape) - 0.3  # rises with y, a few values < 0
    path = write_height_png(tmp_path / "d.png", d_mm, pitch_mm=0.5)
    step = (d_mm.max() - d_mm.min()) / 65535
    back = read_height_png(path)
    assert back.shape == d_mm.shape
    assert np.abs(back - d_mm).max() <= step / 2 * (1 + 1e-9)
    with Image.open(path) as img:
        counts = np.asarray(img).astype(np.int64)
        assert float(img.text["pixel_pitch_mm"]) == 0.5
        assert float(img.text["offset_mm"]) == d_mm.min() and float(img.text["mm_per_count"]) == step
    assert counts.min() == 0 and counts.max() == 65535
    assert counts[0].mean() > counts[-1].mean()  # the image's top row is y = +W


def test_png_of_non_negative_heights_has_offset_zero_and_a_flat_field_reads_back(tmp_path):
    d_mm = paraboloid_cap(16) * MM
    write_height_png(tmp_path / "d.png", d_mm, pitch_mm=1.0)
    with Image.open(tmp_path / "d.png") as img:
        assert float(img.text["offset_mm"]) == 0.0
    write_height_png(tmp_path / "flat.png", np.full((4, 4), 2.0), pitch_mm=1.0)  # 65535 counts of 2 / 65535 mm
    np.testing.assert_allclose(read_height_png(tmp_path / "flat.png"), 2.0, rtol=1e-15)
    write_height_png(tmp_path / "zero.png", np.zeros((4, 4)), pitch_mm=1.0)
    np.testing.assert_array_equal(read_height_png(tmp_path / "zero.png"), np.zeros((4, 4)))


def box(m: int = 12, value: float = 0.04, cols: slice = slice(4, 8)) -> np.ndarray:
    d = np.zeros((m, m))
    d[4:8, cols] = value
    return d


def test_deviation_of_a_scaled_design_equals_the_hand_computed_numbers():
    # 16 of 144 samples at 0.04 scene units planned, 0.05 printed; W = 1.1: pitch 0.2, cell 0.04.
    report = deviation_report(box(value=0.05), box(), 1.1, MM)
    assert report["max_abs_mm"] == pytest.approx(0.25)
    assert report["mean_mm"] == pytest.approx(0.25 * 16 / 144)
    assert report["rms_mm"] == pytest.approx(0.25 / 3)
    assert report["rms_printed_mm"] == pytest.approx(0.25)
    assert report["printed_fraction"] == pytest.approx(16 / 144)
    assert report["planned_volume_mm3"] == pytest.approx(400.0)  # 16 * 0.04 * 0.04 * 25^3
    assert report["printed_volume_mm3"] == pytest.approx(500.0)
    assert report["volume_ratio"] == pytest.approx(1.25)


def test_deviation_of_a_shifted_design_equals_the_hand_computed_numbers():
    # Two columns to the right: 8 samples +1 mm, 8 samples -1 mm, 8 overlap; printed area 24 samples
    # (tails below PRINTED, as smooth designs have, are not printed).
    tail = np.full((12, 12), PRINTED / 2)
    report = deviation_report(box(cols=slice(6, 10)) + tail, box() + tail, 1.1, MM)
    assert report["max_abs_mm"] == pytest.approx(1.0)
    assert report["mean_mm"] == pytest.approx(0.0, abs=1e-15)
    assert report["rms_mm"] == pytest.approx(1.0 / 3)
    assert report["rms_printed_mm"] == pytest.approx(math.sqrt(16 / 24))
    assert report["printed_fraction"] == pytest.approx(24 / 144)
    assert report["volume_ratio"] == pytest.approx(1.0)
    assert deviation_report(np.zeros((4, 4)), np.zeros((4, 4)), 1.0, MM)["volume_ratio"] is None


def test_export_with_a_design_writes_the_deviation_files(tmp_path):
    result = export_outputs(tmp_path, box(value=0.05), 1.1, H, MM, design=box(), formats="ply")
    assert json.loads((tmp_path / "deviation.json").read_text()) == result["deviation"]
    assert result["deviation"]["max_abs_mm"] == pytest.approx(0.25)
    assert {p.name for p in result["files"]} == {"height_field_mm.npy", "height_field_mm.png", "glass.ply",
                                                 "deviation.json", "deviation.png"}
    with Image.open(tmp_path / "deviation.png") as img:
        assert img.size[0] > 3 * img.size[1] > 600


@pytest.mark.parametrize(("d", "h", "words"), [
    (np.where(np.eye(4, dtype=bool), np.nan, 0.0), H, ["d[0, 0]=nan", "not finite"]),
    (np.zeros((3, 4)), H, ["(3, 4)", "square"]),
    (np.zeros((1, 1)), H, ["(1, 1)", "m >= 2"]),
    (np.array([[0.0, -0.25], [0.0, 0.0]]), H, ["h + d = -0.15", "d[0, 1]=-0.25", "thickness=0.1"]),
    (np.zeros((3, 3)), 0.0, ["h + d = 0", "thickness=0.0"]),
])
def test_bad_heights_are_refused_naming_the_value(d, h, words):
    with pytest.raises(ValueError) as error:
        glass_mesh(d, W, h, MM)
    assert all(word in str(error.value) for word in words), str(error.value)


@pytest.mark.parametrize("mm_per_unit", [0.0, -2.5, float("nan")])
def test_mm_per_unit_that_is_not_positive_is_refused(mm_per_unit):
    with pytest.raises(ValueError, match=rf"mm_per_unit={mm_per_unit!r} must be a length > 0"):
        glass_mesh(np.zeros((3, 3)), W, H, mm_per_unit)
    with pytest.raises(ValueError, match=rf"mm_per_unit={mm_per_unit!r}"):
        deviation_report(np.zeros((3, 3)), np.zeros((3, 3)), W, mm_per_unit)


def test_unknown_format_is_refused_before_anything_is_written(tmp_path):
    with pytest.raises(ValueError, match=r"unknown mesh format 'step'; use one or more of stl, obj, ply"):
        export_outputs(tmp_path / "out", np.zeros((3, 3)), W, H, MM, formats=("stl", "step"))
    assert not (tmp_path / "out").exists()


def test_other_bad_inputs_name_the_value(tmp_path):
    with pytest.raises(ValueError, match=r"design has shape \(4, 4\), the reconstruction \(3, 3\)"):
        deviation_report(np.zeros((3, 3)), np.zeros((4, 4)), W, MM)
    with pytest.raises(ValueError, match=r"half_width=0.0 must be a positive number \(scene units\)"):
        glass_mesh(np.zeros((3, 3)), 0.0, H, MM)
    Image.fromarray(np.zeros((4, 4), dtype=np.uint16)).save(tmp_path / "plain.png")
    with pytest.raises(ValueError, match=r"has no PNG text key 'mm_per_count'"):
        read_height_png(tmp_path / "plain.png")


def test_a_refined_mesh_samples_the_models_surface_between_the_samples():
    """refine=3: the top's grid vertices are the operators' Catmull-Rom surface (its scalar kernel)
    at three points per spacing, through every sample; the mesh stays closed; refine 0 is refused."""
    from operators.heightfield.catmull_rom import axis_weights, contract, load_patch

    d = np.random.default_rng(3).random((6, 6)) * 0.05
    mesh = glass_mesh(d, W, H, MM, refine=3)
    assert mesh.is_watertight
    fine = np.linspace(-W, W, 16)
    spacing, wx, wy, patch = 2.0 * W / 5, np.zeros((4, 4)), np.zeros((4, 4)), np.zeros((4, 4))
    tops = np.asarray(mesh.vertices)[:16 * 16, 2].reshape(16, 16) / MM
    for i, y in enumerate(fine):
        for j, x in enumerate(fine):
            load_patch(d, axis_weights(x, -W, spacing, 6, 0, wx), axis_weights(y, -W, spacing, 6, 0, wy), patch)
            assert tops[i, j] == pytest.approx(H + contract(patch, wx, 0, wy, 0), abs=1e-12)
    np.testing.assert_allclose(tops[::3, ::3], H + d, atol=1e-12)
    with pytest.raises(ValueError, match="refine=0"):
        glass_mesh(d, W, H, MM, refine=0)
