"""Photo import (framework/lab/photo_import.py, photo_geometry.py, photo_synthesis.py): geometry,
linearisation, dark/flat/saturation, refusals."""

from __future__ import annotations

import doctest
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import framework.lab.photo_geometry
from framework.lab.photo_figure import save_photo_figure
from framework.lab.photo_import import import_photo, linearize, read_photo
from framework.lab.photo_geometry import check_corners, homography, rectify
from framework.lab.photo_synthesis import synthesize_photo, vignetting_field

N = 64
SHAPE = (260, 300)  # photo (H, W)
CORNERS = [[40.0, 230.0], [250.0, 220.0], [240.0, 20.0], [30.0, 40.0]]  # BL, BR, TR, TL: about 3.2 px per pixel


def smooth_image(n: int = N) -> np.ndarray:
    """A smooth, asymmetric receiver image (1, n, n), rows y-up, values in [0.4, 1.8]."""
    y, x = np.mgrid[0:n, 0:n]
    xs, ys = (x + 0.5) / n * 2 - 1, (y + 0.5) / n * 2 - 1
    return (1 + 0.5 * np.sin(2 * xs) * np.cos(3 * ys) + 0.3 * np.exp(-((xs - 0.3) ** 2 + (ys + 0.2) ** 2) / 0.1))[None]


def box_average(image: np.ndarray) -> np.ndarray:
    """Exact pixel-box mean of the bilinear interpolant of ``image`` (edge values extended):
    weights 1/8, 3/4, 1/8 along each axis."""
    p = np.pad(image, ((0, 0), (1, 1), (1, 1)), mode="edge")
    rows = (p[:, :-2] + 6 * p[:, 1:-1] + p[:, 2:]) / 8
    return (rows[:, :, :-2] + 6 * rows[:, :, 1:-1] + rows[:, :, 2:]) / 8


def rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def rel_up_to_scale(a: np.ndarray, b: np.ndarray) -> float:
    """Relative error of ``a`` against ``b`` after the least-squares scale (the import's scale is arbitrary)."""
    return rel(float((a * b).sum() / (a * a).sum()) * a, b)


def save(array: np.ndarray, path: Path) -> Path:
    Image.fromarray(array).save(path)
    return path


def project(h: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    p = h @ np.stack([x, y, np.ones_like(x)])
    return p[0] / p[2], p[1] / p[2]


# --- geometry ------------------------------------------------------------------------------------

def test_homography_maps_the_four_corners_exactly() -> None:
    w = 2.5
    h = homography(CORNERS, w)
    col, row = project(h, np.array([-w, w, w, -w]), np.array([-w, -w, w, w]))
    assert np.abs(np.stack([col, row], axis=1) - np.array(CORNERS)).max() < 1e-9
    assert h.shape == (3, 3) and h[2, 2] == 1.0


def test_homography_recovers_a_known_projective_map() -> None:
    w = 1.5
    known = np.array([[80.0, 12.0, 400.0], [-9.0, -70.0, 300.0], [0.04, -0.07, 1.0]])
    cx, cy = project(known, np.array([-w, w, w, -w]), np.array([-w, -w, w, w]))
    h = homography(np.stack([cx, cy], axis=1), w)
    assert np.abs(h - known).max() < 1e-9 * np.abs(known).max()
    x, y = np.random.default_rng(0).uniform(-w, w, (2, 1000))
    assert np.abs(np.stack(project(h, x, y)) - np.stack(project(known, x, y))).max() < 1e-8


def test_homography_doctest() -> None:
    result = doctest.testmod(framework.lab.photo_geometry, extraglobs={"np": np})
    assert result.failed == 0 and result.attempted > 0


def test_rectify_block_photo_exactly_and_rows_point_up() -> None:
    """A photo made of 8 x 8 blocks, receiver edges on block edges: each receiver pixel is its block's value."""
    n, margin = 16, 5
    values = np.random.default_rng(3).uniform(0, 1, (n, n))  # receiver [row = y up, col = x]
    photo = np.zeros((n * 8 + 2 * margin,) * 2)
    photo[margin:-margin, margin:-margin] = np.kron(values[::-1], np.ones((8, 8)))  # photo row 0 = top
    lo, hi = margin - 0.5, margin + 8 * n - 0.5
    h = homography([[lo, hi], [hi, hi], [hi, lo], [lo, lo]], 1.0)
    out = rectify(photo, h, n, 1.0, supersample=4)
    assert out.shape == (1, n, n) and np.abs(out[0] - values).max() < 1e-12


def test_rectify_recovers_a_synthetic_photo() -> None:
    """Measured: 3.7e-5 against the exact box average, 5.3e-4 against the pixel values."""
    image = smooth_image()
    photo = synthesize_photo(image, CORNERS, SHAPE, 1.0, gain=0.5, extend_edges=True)
    out = rectify(photo / 65535.0, homography(CORNERS, 1.0), N, 1.0, supersample=4) / 0.5
    assert rel(out, box_average(image)) < 1e-4
    assert rel(out, image) < 1e-3
    # with nothing outside the receiver only the outer ring of receiver pixels suffers (measured 4.9e-4)
    photo = synthesize_photo(image, CORNERS, SHAPE, 1.0, gain=0.5)
    out = rectify(photo / 65535.0, homography(CORNERS, 1.0), N, 1.0, supersample=4) / 0.5
    assert rel(out[:, 1:-1, 1:-1], image[:, 1:-1, 1:-1]) < 1e-3
    assert rel(out, image) > 5e-3


def test_check_corners_accepts_a_mirrored_view_and_returns_floats() -> None:
    mirrored = [CORNERS[1], CORNERS[0], CORNERS[3], CORNERS[2]]
    assert check_corners(mirrored, SHAPE).dtype == np.float64


@pytest.mark.parametrize(("corners", "message"), [
    ([[40, 230], [310, 220], [240, 20], [30, 40]], r"\[310\.0, 220\.0\] lies outside the 300 x 260 photo"),
    ([[40, 230], [250, 220], [120, 150], [30, 40]], r"not convex \(at corner top-right"),
    ([[40, 230], [250, 220], [30, 40], [240, 20]], "self-intersecting"),
    ([[40, 230], [250, 220], [240, 20]], r"shape \(3, 2\)"),
    ([[10, 10], [20, 10], [30, 10], [10, 20]], "collinear at bottom-right"),
    ([[10, 12], [12, 12], [12, 10], [10, 10]], "degenerate quadrilateral \\(area 4"),
    ([[40, 230], [250, np.nan], [240, 20], [30, 40]], "NaN"),
])
def test_bad_corners_are_refused(corners: list, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        check_corners(corners, SHAPE)


# --- reading and linearising ---------------------------------------------------------------------

def test_read_photo_scales_8_and_16_bit_and_keeps_npy(tmp_path: Path) -> None:
    grey16 = np.arange(12, dtype=np.uint16).reshape(3, 4) * 5000
    values, depth = read_photo(save(grey16, tmp_path / "g.png"))
    assert depth == 16 and np.array_equal(values, grey16 / 65535.0)
    rgb8 = np.arange(36, dtype=np.uint8).reshape(3, 4, 3) * 7
    values, depth = read_photo(save(rgb8, tmp_path / "c.tif"), bit_depth=8)
    assert depth == 8 and values.shape == (3, 4, 3) and np.array_equal(values, rgb8 / 255.0)
    np.save(tmp_path / "l.npy", grey16 / 70000.0)
    values, depth = read_photo(tmp_path / "l.npy")
    assert depth == 0 and np.array_equal(values, grey16 / 70000.0)


def write_png_rgb16(array: np.ndarray, path: Path) -> Path:
    """A 16-bit RGB PNG written by hand (Pillow cannot write one)."""
    height, width, _ = array.shape
    raw = b"".join(b"\x00" + row.astype(">u2").tobytes() for row in array)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 16, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw))
                     + chunk(b"IEND", b""))
    return path


def test_unsupported_photos_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"f\.tif is a 32-bit float image \(mode 'F'\)"):
        read_photo(save(np.ones((4, 4), np.float32), tmp_path / "f.tif"))
    with pytest.raises(ValueError, match=r"b\.png is a 1-bit .*mode '1'"):
        read_photo(save(np.ones((4, 4), bool), tmp_path / "b.png"))
    with pytest.raises(ValueError, match=r"i\.tif is a 32-bit integer image \(mode 'I'\)"):
        read_photo(save(np.ones((4, 4), np.int32), tmp_path / "i.tif"))
    Image.new("P", (4, 4)).save(tmp_path / "p.png")
    with pytest.raises(ValueError, match=r"p\.png is a palette image"):
        read_photo(tmp_path / "p.png")
    with pytest.raises(ValueError, match=r"rgb16\.png is a 16-bit RGB image .*16-bit greyscale"):
        read_photo(write_png_rgb16(np.full((3, 4, 3), 60000, np.uint16), tmp_path / "rgb16.png"))
    with pytest.raises(ValueError, match=r"e8\.png is 8-bit but data\.bit_depth=16"):
        read_photo(save(np.ones((4, 4), np.uint8), tmp_path / "e8.png"), bit_depth=16)
    (tmp_path / "x.jpg").write_bytes(b"")
    with pytest.raises(ValueError, match=r"x\.jpg has the unsupported suffix '\.jpg'"):
        read_photo(tmp_path / "x.jpg")
    np.save(tmp_path / "n.npy", np.ones((4, 4), np.int64))
    with pytest.raises(ValueError, match=r"n\.npy holds int64 values"):
        read_photo(tmp_path / "n.npy")
    with pytest.raises(FileNotFoundError, match="missing.png"):
        read_photo(tmp_path / "missing.png")
    with pytest.raises(ValueError, match="data.bit_depth=12"):
        read_photo(tmp_path / "e8.png", bit_depth=12)


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1)."""
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)


def test_linearize_inverts_srgb_and_gamma() -> None:
    x = np.linspace(0.0, 1.0, 100001)
    assert np.abs(linearize(srgb_encode(x), "srgb") - x).max() < 1e-12
    assert abs(float(linearize(np.array(0.5), "srgb")) - 0.214041) < 1e-6  # sRGB mid grey
    assert np.abs(linearize(x ** (1 / 2.2), "gamma", 2.2) - x).max() < 1e-12
    assert np.array_equal(linearize(x, "linear"), x)
    assert float(linearize(np.array(-0.25), "gamma", 2.0)) == -0.0625  # noise below the black level keeps its sign
    with pytest.raises(ValueError, match="data.response='log'"):
        linearize(x, "log")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="data.gamma=0"):
        linearize(x, "gamma", 0)


# --- the import chain ----------------------------------------------------------------------------

def test_gamma_and_black_level_are_undone(tmp_path: Path) -> None:
    """Measured: 3.6e-5 with both; 2.6e-3 without the black level; 0.14 without the inverse gamma."""
    image = smooth_image()
    photo = synthesize_photo(image, CORNERS, SHAPE, 1.0, gain=0.5, gamma=2.2, black_level_dn=512, extend_edges=True)
    path = save(photo, tmp_path / "g.png")
    result = import_photo(path, CORNERS, 1.0, N, response="gamma", gamma=2.2, black_level=512)
    assert result.image.shape == (1, N, N) and result.image.dtype == np.float64
    assert rel_up_to_scale(result.image, box_average(image)) < 1e-4
    assert "black level 512 DN subtracted" in result.steps and np.all(result.weights == 1.0)
    assert rel_up_to_scale(import_photo(path, CORNERS, 1.0, N, response="gamma", gamma=2.2).image,
                           box_average(image)) > 1e-3
    assert rel_up_to_scale(import_photo(path, CORNERS, 1.0, N, black_level=512).image, box_average(image)) > 0.05


def test_dark_frame_is_subtracted(tmp_path: Path) -> None:
    """A fixed dark pattern of up to 400 DN on a 512 DN black level. Measured: 3.6e-5; 1.8e-3 without it."""
    image = smooth_image()
    pattern = np.random.default_rng(1).integers(0, 400, SHAPE)
    photo = synthesize_photo(image, CORNERS, SHAPE, 1.0, gain=0.5, black_level_dn=512, extend_edges=True)
    path = save((photo + pattern).astype(np.uint16), tmp_path / "d.png")
    dark = save((512 + pattern).astype(np.uint16), tmp_path / "dark.png")
    result = import_photo(path, CORNERS, 1.0, N, dark=dark)
    assert rel_up_to_scale(result.image, box_average(image)) < 1e-4
    assert any(step.startswith("dark frame dark.png subtracted") for step in result.steps)
    assert rel_up_to_scale(import_photo(path, CORNERS, 1.0, N, black_level=512).image, box_average(image)) > 1e-3


def test_flat_field_cancels_vignetting(tmp_path: Path) -> None:
    """30% vignetting: measured 3.6e-5 with the flat field, 3.9e-2 without."""
    image = smooth_image()
    photo = synthesize_photo(image, CORNERS, SHAPE, 1.0, gain=0.5, vignetting=0.3, extend_edges=True)
    flat = synthesize_photo(np.ones((1, N, N)), CORNERS, SHAPE, 1.0, gain=0.8, vignetting=0.3, extend_edges=True)
    field = vignetting_field(SHAPE, 0.3)
    assert abs(field.min() - 0.7) < 0.01 and field.max() <= 1.0
    path, flat_path = save(photo, tmp_path / "v.png"), save(flat, tmp_path / "flat.png")
    result = import_photo(path, CORNERS, 1.0, N, flat=flat_path)
    assert rel_up_to_scale(result.image, box_average(image)) < 1e-4 and np.all(result.weights == 1.0)
    assert any(step.startswith("flat field flat.png divided") for step in result.steps)
    assert rel_up_to_scale(import_photo(path, CORNERS, 1.0, N).image, box_average(image)) > 0.02


BLOCK_N, MARGIN = 16, 5  # receiver pixel (i, j) <-> photo rows 5 + 8 (15 - i) .. +7, cols 5 + 8 j .. +7
BLOCK_SHAPE = (BLOCK_N * 8 + 2 * MARGIN,) * 2
LO, HI = MARGIN - 0.5, MARGIN + 8 * BLOCK_N - 0.5
BLOCK_CORNERS = [[LO, HI], [HI, HI], [HI, LO], [LO, LO]]


def test_saturated_pixels_zero_exactly_their_receiver_pixels(tmp_path: Path) -> None:
    photo = synthesize_photo(smooth_image(BLOCK_N), BLOCK_CORNERS, BLOCK_SHAPE, 1.0, gain=0.5)
    clipped = [(5 + 8 * 3 + 7, 5 + 8 * 10), (5 + 8 * 3 + 7, 5 + 8 * 10 + 1), (5, 5 + 8 * 15 + 7), (100, 60), (0, 0)]
    for row, col in clipped:
        photo[row, col] = 65535
    result = import_photo(save(photo, tmp_path / "s.png"), BLOCK_CORNERS, 1.0, BLOCK_N)
    expected = np.ones((BLOCK_N, BLOCK_N))
    for row, col in clipped[:-1]:  # (0, 0) lies outside the receiver
        expected[BLOCK_N - 1 - (row - MARGIN) // 8, (col - MARGIN) // 8] = 0.0
    assert np.array_equal(result.weights[0], expected)
    assert "5 saturated photo pixels (raw >= 0.98) -> 3 receiver pixels left out (weight 0)" in result.steps
    assert result.left_out == {"saturated": 3}
    assert result.image[0, BLOCK_N - 1 - 3, 10] > result.image[0, BLOCK_N - 1 - 3, 9]  # kept, not clipped
    # a flat field with a dead pixel: its receiver pixel goes too
    flat = np.full(BLOCK_SHAPE, 40000, np.uint16)
    flat[5 + 8 * 12 + 2, 5 + 8 * 4 + 3] = 0
    flat_result = import_photo(tmp_path / "s.png", BLOCK_CORNERS, 1.0, BLOCK_N, flat=save(flat, tmp_path / "f.png"))
    expected[BLOCK_N - 1 - 12, 4] = 0.0
    assert np.array_equal(flat_result.weights[0], expected)
    # an even flat normalised by its mean changes nothing but the dead pixel's neighbourhood (mean 1 - 1/16384)
    kept = expected > 0
    assert np.abs(flat_result.image[0][kept] / result.image[0][kept] - 1.0).max() < 1e-4


def test_saturation_is_checked_in_the_used_channel(tmp_path: Path) -> None:
    photo = synthesize_photo(smooth_image(BLOCK_N), BLOCK_CORNERS, BLOCK_SHAPE, 1.0, gain=0.5, bit_depth=8)
    rgb = np.repeat(photo[..., None], 3, axis=2)
    rgb[60, 60, 0] = 255  # red clipped only
    path = save(rgb, tmp_path / "rgb.png")
    assert int((import_photo(path, BLOCK_CORNERS, 1.0, BLOCK_N, channel="green").weights == 0).sum()) == 0
    assert int((import_photo(path, BLOCK_CORNERS, 1.0, BLOCK_N, channel="grey").weights == 0).sum()) == 1


def test_bad_imports_are_refused(tmp_path: Path) -> None:
    photo = save(synthesize_photo(smooth_image(), CORNERS, SHAPE, 1.0, gain=0.5), tmp_path / "p.png")
    with pytest.raises(ValueError, match=r"flat field small\.png is 200 x 100 grey but the photo is 300 x 260 grey"):
        import_photo(photo, CORNERS, 1.0, N, flat=save(np.ones((100, 200), np.uint16), tmp_path / "small.png"))
    with pytest.raises(ValueError, match=r"sat\.png: 4096 of 4096 receiver pixels \(100%"):
        import_photo(save(np.full(SHAPE, 65535, np.uint16), tmp_path / "sat.png"), CORNERS, 1.0, N)
    with pytest.raises(ValueError, match=r"dim\.png is all zero after subtracting data\.black_level=600 DN"):
        import_photo(save(np.full(SHAPE, 580, np.uint16), tmp_path / "dim.png"), CORNERS, 1.0, N, black_level=600)
    with pytest.raises(ValueError, match=r"p\.png is 16-bit but data\.bit_depth=8"):
        import_photo(photo, CORNERS, 1.0, N, bit_depth=8)
    with pytest.raises(ValueError, match=r"lies outside the 300 x 260 photo"):
        import_photo(photo, [[40, 230], [250, 220], [240, 20], [30, -4]], 1.0, N)
    with pytest.raises(ValueError, match="data.channel='cyan'"):
        import_photo(photo, CORNERS, 1.0, N, channel="cyan")  # type: ignore[arg-type]
    with pytest.raises(FileNotFoundError, match="nothing.png"):
        import_photo(photo, CORNERS, 1.0, N, dark=tmp_path / "nothing.png")


def test_figure_is_written(tmp_path: Path) -> None:
    photo = synthesize_photo(smooth_image(BLOCK_N), BLOCK_CORNERS, BLOCK_SHAPE, 1.0, gain=0.5)
    photo[60, 60] = 65535
    result = import_photo(save(photo, tmp_path / "s.png"), BLOCK_CORNERS, 1.0, BLOCK_N)
    path = save_photo_figure(tmp_path / "fig" / "photo.png", result)
    with Image.open(path) as img:
        assert img.size[0] > 1000 and img.size[1] > 400
