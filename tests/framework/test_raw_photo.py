"""Camera RAW photos read linearly (framework/lab/raw_photo.py), against DNG files of known sensor
counts (framework/lab/photo_synthesis.py ``write_dng``) and LibRaw's own rendering."""

from __future__ import annotations

import numpy as np
import pytest
import rawpy

from framework.lab.photo_import import import_photo, read_photo
from framework.lab.photo_synthesis import write_dng
from framework.lab.raw_photo import read_raw

H, W = 64, 96
BLACK, WHITE = (500, 520, 540), 16000


def _ramp() -> np.ndarray:
    """(H, W, 3) linear values: a ramp along x, R, 0.8 G, 0.5 B."""
    ramp = np.tile(np.linspace(0.02, 0.9, W), (H, 1))
    return np.stack([ramp, 0.8 * ramp, 0.5 * ramp], axis=-1)


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_a_dng_of_a_linear_ramp_reads_back_linear_with_the_files_levels(tmp_path, pattern):
    path = write_dng(tmp_path / "ramp.dng", _ramp(), black=BLACK, white=WHITE, pattern=pattern)
    frame = read_raw(path)
    assert frame.pattern == pattern and frame.black == BLACK and frame.white == WHITE
    # each photosite was rounded to a whole count, and bilinear interpolation keeps a ramp: half a
    # count of each colour's range at most, inside the one-pixel border (mirrored there)
    quantum = 0.5 / (WHITE - np.array(BLACK, dtype=float))
    assert np.all(np.abs(frame.values - _ramp())[1:-1, 1:-1].max(axis=(0, 1)) <= quantum + 1e-12)
    values, depth = read_photo(path)
    np.testing.assert_array_equal(values, frame.values)


def test_the_frame_is_turned_as_the_file_says_the_camera_was_held(tmp_path):
    rgb = np.zeros((H, W, 3))
    rgb[:4, :4] = 0.9  # a bright block at the stored image's top left
    # TIFF orientation -> the (row, col) corner where a viewer shows that block
    for orientation, corner in ((1, (0, 0)), (3, (H - 1, W - 1)), (6, (0, H - 1)), (8, (W - 1, 0))):
        path = write_dng(tmp_path / f"o{orientation}.dng", rgb, orientation=orientation)
        values = read_raw(path).values[..., 1]
        with rawpy.imread(str(path)) as raw:  # LibRaw's own rendering, turned as the file says
            shown = raw.postprocess(gamma=(1, 1), no_auto_bright=True, output_bps=16)[..., 1]
        assert values.shape == shown.shape
        bright = {(int(r), int(c)) for r, c in np.argwhere(values > 0.5)}
        assert 12 <= len(bright) <= 20 and corner in bright
        assert tuple(int(v) for v in np.unravel_index(np.argmax(shown), shown.shape)) in bright


def test_a_photosite_at_the_white_level_marks_its_cell_for_the_saturation_test(tmp_path):
    rgb = np.full((H, W, 3), 0.5)
    path = write_dng(tmp_path / "flat.dng", rgb, black=BLACK, white=WHITE)
    with rawpy.imread(str(path)) as raw:
        counts = raw.raw_image_visible.copy()
    frame = read_raw(path)
    assert np.all(np.abs(frame.values - 0.5) < 1e-4)
    rgb[10, 21, 1] = 1.0  # the green photosite at row 10, column 21 (RGGB: G at even rows, odd columns) saturated
    path = write_dng(tmp_path / "hot.dng", rgb, black=BLACK, white=WHITE)
    values = read_raw(path).values
    hot = values[..., 1] == 1.0
    # the photosite and the four pixels whose green interpolation uses it read saturated, no other
    assert set(zip(*np.nonzero(hot))) == {(10, 21), (9, 21), (11, 21), (10, 20), (10, 22)}
    assert np.all(np.abs(values[..., [0, 2]] - 0.5) < 1e-4) and np.all(np.abs(values[~hot, 1] - 0.5) < 1e-4)
    assert counts.max() < WHITE


def test_a_dng_imports_as_its_linear_values_do(tmp_path):
    """The whole import on the DNG and on the same linear values as a .npy: the same receiver image."""
    rgb = _ramp() * np.linspace(0.6, 1.0, H)[:, None, None]
    path = write_dng(tmp_path / "photo.dng", rgb, black=BLACK, white=WHITE)
    np.save(tmp_path / "photo.npy", read_raw(path).values)
    corners = [[4, 60], [90, 60], [90, 3], [4, 3]]
    from_raw = import_photo(path, corners, 1.0, 16, channel="green")
    from_npy = import_photo(tmp_path / "photo.npy", corners, 1.0, 16, channel="green")
    np.testing.assert_array_equal(from_raw.image, from_npy.image)
    assert "camera RAW, RGGB mosaic read linearly (black 500, 520, 540, white 16000" in from_raw.steps[0]
    assert "each colour interpolated bilinearly from its photosites" in from_raw.steps[0]
    green = 0.8 * rgb[..., 0].mean()
    assert abs(float(from_raw.image.mean()) - green) < 0.05 * green


@pytest.mark.parametrize("settings, message", [
    ({"black_level": 512}, "is a camera RAW file, read linearly with the file's black level; drop "
                           "data.black_level=512"),
    ({"response": "gamma"}, "and data.response='gamma'"),
    ({"bit_depth": 16}, "is a camera RAW file but data.bit_depth=16; set data.bit_depth=null"),
    ({"flat": "flat.png"}, "flat field flat.png is 8-bit but the photo is a camera RAW file"),
])
def test_raw_settings_that_do_not_apply_are_refused_in_one_line(tmp_path, settings, message):
    from PIL import Image

    write_dng(tmp_path / "photo.dng", _ramp())
    Image.fromarray(np.full((H, W), 200, np.uint8)).save(tmp_path / "flat.png")
    settings = {k: tmp_path / v if k == "flat" else v for k, v in settings.items()}
    with pytest.raises(ValueError, match=message) as error:
        import_photo(tmp_path / "photo.dng", [[4, 60], [90, 60], [90, 3], [4, 3]], 1.0, 16, **settings)
    assert "\n" not in str(error.value)


def test_a_raw_file_libraw_cannot_read_is_refused_in_one_line(tmp_path):
    (tmp_path / "shot.nef").write_bytes(b"not a raw file" * 100)
    with pytest.raises(ValueError, match=r"photo shot.nef cannot be read as a camera RAW file by LibRaw .*"
                                         r"pip install -U rawpy.*dcraw") as error:
        read_photo(tmp_path / "shot.nef")
    assert "\n" not in str(error.value)
