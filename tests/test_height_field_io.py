"""Height-field files: round trips, orientation, resampling and every refused input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from framework.files.height_field_io import load_height_field, resample, save_height_field
from framework.scene.printed_shapes import make_shape


@pytest.fixture()
def heights() -> np.ndarray:
    return make_shape("bump", 33, center=[0.3, -0.2], sigma=0.2, height=0.08)


def test_npy_round_trip_is_exact(tmp_path: Path, heights: np.ndarray) -> None:
    scale = save_height_field(tmp_path / "d.npy", heights)
    assert scale == 1.0
    np.testing.assert_array_equal(load_height_field(tmp_path / "d.npy"), heights)


def test_npy_accepts_a_tensor_and_applies_scale(tmp_path: Path, heights: np.ndarray) -> None:
    save_height_field(tmp_path / "d.npy", torch.from_numpy(heights).float())
    np.testing.assert_allclose(load_height_field(tmp_path / "d.npy", scale=2.0), 2.0 * heights, rtol=1e-6)


@pytest.mark.parametrize("suffix", [".png", ".tif"])
def test_16_bit_image_round_trip(tmp_path: Path, heights: np.ndarray, suffix: str) -> None:
    path = tmp_path / f"d{suffix}"
    scale = save_height_field(path, heights)
    assert scale == pytest.approx(heights.max())
    with Image.open(path) as img:
        assert img.mode.startswith("I")
    np.testing.assert_allclose(load_height_field(path, scale=scale), heights, rtol=0, atol=scale / 65535)


def test_images_are_stored_with_plus_y_up(tmp_path: Path) -> None:
    d = np.zeros((8, 8))
    d[-1, 2] = 0.1  # last array row = y = +1
    save_height_field(tmp_path / "d.png", d, scale=0.1)
    raw = np.asarray(Image.open(tmp_path / "d.png"))
    assert raw[0, 2] == 65535 and raw.sum() == 65535


def test_8_bit_png_is_value_over_255_times_scale(tmp_path: Path) -> None:
    grey = np.arange(16 * 16, dtype=np.uint8).reshape(16, 16)
    Image.fromarray(grey).save(tmp_path / "g.png")
    loaded = load_height_field(tmp_path / "g.png", scale=0.3)
    np.testing.assert_allclose(loaded, grey[::-1] / 255.0 * 0.3, rtol=1e-12)


def test_resampling_up_and_down(tmp_path: Path, heights: np.ndarray) -> None:
    np.save(tmp_path / "d.npy", heights)
    up = load_height_field(tmp_path / "d.npy", resolution=65)
    assert up.shape == (65, 65) and up.min() >= 0.0
    np.testing.assert_allclose(up[::2, ::2], heights, atol=1e-12)  # aligned corners keep the samples
    down = load_height_field(tmp_path / "d.npy", resolution=16)
    assert down.shape == (16, 16) and 0.0 < down.max() <= heights.max()
    np.testing.assert_array_equal(load_height_field(tmp_path / "d.npy", resolution=33), heights)


def test_missing_file_names_the_path(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="nothing_here.npy"):
        load_height_field(tmp_path / "nothing_here.npy")


@pytest.mark.parametrize("array, message", [
    (np.zeros((4, 4, 4)), "square 2-D array, got shape \\(4, 4, 4\\)"),
    (np.zeros((4, 5)), "square 2-D array, got shape \\(4, 5\\)"),
    (np.full((4, 4), np.nan), "NaN"),
    (-np.ones((4, 4)), "negative values"),
])
def test_bad_arrays_are_refused(tmp_path: Path, array: np.ndarray, message: str) -> None:
    np.save(tmp_path / "bad.npy", array)
    with pytest.raises(ValueError, match=message):
        load_height_field(tmp_path / "bad.npy")


def test_colour_image_is_refused(tmp_path: Path) -> None:
    Image.fromarray(np.zeros((8, 8, 3), dtype=np.uint8)).save(tmp_path / "rgb.png")
    with pytest.raises(ValueError, match="mode 'RGB'.*greyscale"):
        load_height_field(tmp_path / "rgb.png")


def test_unknown_suffix_and_bad_scale(tmp_path: Path) -> None:
    (tmp_path / "d.txt").write_text("0")
    with pytest.raises(ValueError, match="suffix '.txt'"):
        load_height_field(tmp_path / "d.txt")
    np.save(tmp_path / "d.npy", np.zeros((4, 4)))
    with pytest.raises(ValueError, match="scale=-1.0"):
        load_height_field(tmp_path / "d.npy", scale=-1.0)
    with pytest.raises(ValueError, match="resolution=1"):
        resample(np.zeros((4, 4)), 1)


def test_saving_above_the_image_scale_is_refused(tmp_path: Path, heights: np.ndarray) -> None:
    with pytest.raises(ValueError, match="exceeds scale"):
        save_height_field(tmp_path / "d.png", heights, scale=0.01)
    with pytest.raises(ValueError, match="negative"):
        save_height_field(tmp_path / "d.npy", -heights - 1.0)


def test_a_corrupt_npy_is_one_line_naming_the_file(tmp_path: Path) -> None:
    np.save(tmp_path / "d.npy", np.zeros((8, 8)))
    data = (tmp_path / "d.npy").read_bytes()
    (tmp_path / "d.npy").write_bytes(data[:100])
    with pytest.raises(ValueError) as refused:
        load_height_field(tmp_path / "d.npy")
    message = str(refused.value)
    assert "\n" not in message and message == (f"{tmp_path / 'd.npy'} is corrupt or truncated (not a complete .npy "
                                               "array of numbers); save the heights again with numpy.save")
