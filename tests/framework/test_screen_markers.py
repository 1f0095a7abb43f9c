"""The receiver found by its printed markers (framework/lab/screen_markers.py): synthetic photos of
the sheet through known homographies, turned, small, blurred, noisy and partly covered."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from framework.lab.screen_markers import MarkerSheet, detect_receiver

SHEET = MarkerSheet(receiver_mm=50.0, marker_mm=6.0, gap_mm=2.0, per_side=4)
DPI = 254.0  # 10 dots a mm: every marker edge on a whole page pixel, so the page is the layout exactly
PER_MM = DPI / 25.4


def _photo(corners_px, shape=(1100, 1300), blur=1.0, noise=0.01, covered=(), seed=0):
    """A photo of the sheet whose page corners (top-left, top-right, bottom-right, bottom-left of
    the page) land at ``corners_px``; markers ``covered`` painted over. Returns the linear photo
    and the receiver's true corners (bottom-left, bottom-right, top-right, top-left)."""
    page = SHEET.render(DPI).astype(np.float64) / 255
    size = page.shape[0]
    for marker_id in covered:
        x, y = SHEET.centres()[marker_id]
        col, row = int(x * PER_MM + size / 2), int(size / 2 - y * PER_MM)
        half = int(0.6 * SHEET.marker_mm * PER_MM)
        page[row - half:row + half, col - half:col + half] = 0.5
    src = np.float32([[-0.5, -0.5], [size - 0.5, -0.5], [size - 0.5, size - 0.5], [-0.5, size - 0.5]])
    h = cv2.getPerspectiveTransform(src, np.float32(corners_px)).astype(np.float64)
    photo = cv2.warpPerspective(page, h, shape[::-1], flags=cv2.INTER_AREA, borderValue=0.15)
    if blur:
        photo = cv2.GaussianBlur(photo, (0, 0), blur)
    photo = 0.6 * photo + np.random.default_rng(seed).normal(0.0, noise, photo.shape)
    half = SHEET.receiver_mm / 2
    receiver_mm = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
    page_px = np.c_[receiver_mm[:, 0] * PER_MM + size / 2 - 0.5, size / 2 - receiver_mm[:, 1] * PER_MM - 0.5]
    return np.clip(photo, 0.0, 1.0), cv2.perspectiveTransform(page_px[None], h)[0]


VIEWS = {
    "oblique": [[210, 140], [1150, 180], [1100, 1020], [170, 960]],
    "turned 90 degrees": [[1150, 120], [1180, 1000], [280, 1030], [250, 150]],
    "turned 30 degrees": [[450, 40], [1230, 480], [850, 1080], [60, 650]],
    "small": [[550, 450], [850, 465], [845, 760], [548, 752]],
}


@pytest.mark.parametrize("view", list(VIEWS))
def test_the_receiver_corners_are_found_to_a_fraction_of_a_pixel(view):
    photo, truth = _photo(VIEWS[view])
    fit = detect_receiver(photo, SHEET)
    assert fit.found == tuple(range(12)) and not fit.rejected
    error = np.linalg.norm(fit.corners - truth, axis=1)
    assert error.max() < 0.25, error  # measured 0.02-0.16 px, on receivers 300 to 950 px wide
    assert np.all(fit.corner_std > 0) and fit.corner_std.max() < 0.2 and fit.rms_px < 0.25


def test_blur_and_covered_markers_cost_little():
    photo, truth = _photo(VIEWS["oblique"], blur=2.5, noise=0.02, covered=(0, 4, 5, 9))
    fit = detect_receiver(photo, SHEET)
    assert set(fit.found) == set(range(12)) - {0, 4, 5, 9}
    assert np.linalg.norm(fit.corners - truth, axis=1).max() < 0.2  # measured 0.12 px


def test_too_few_markers_are_refused_in_one_line_naming_the_ones_found():
    photo, _ = _photo(VIEWS["oblique"], covered=tuple(range(2, 12)))
    with pytest.raises(ValueError, match=r"print.png: 2 of the 12 markers of DICT_4X4_50 found \(ids 0, 1\), at "
                                         r"least 3 needed;.*or type data.corners") as error:
        detect_receiver(photo, SHEET, "print.png")
    assert "\n" not in str(error.value)


def test_the_sheet_saves_a_png_at_its_size_and_a_layout_that_loads_back(tmp_path):
    from PIL import Image

    png, layout = SHEET.save(tmp_path / "sheet", dpi=DPI)
    assert MarkerSheet.load(layout) == SHEET
    with Image.open(png) as image:
        assert image.info["dpi"] == pytest.approx((DPI, DPI))
        assert image.size[0] / DPI * 25.4 == pytest.approx(SHEET.page_mm(), abs=0.1)
    with pytest.raises(ValueError, match="is not a marker layout written by sfc-markers"):
        MarkerSheet.load(png)


@pytest.mark.parametrize("settings, message", [
    ({"receiver_mm": 0}, "markers.receiver_mm=0 must be a length > 0 in mm"),
    ({"receiver_mm": 50, "dictionary": "DICT_9X9_1"}, "markers.dictionary='DICT_9X9_1' is not an OpenCV ArUco"),
    ({"receiver_mm": 50, "per_side": 30}, "116 markers need a dictionary with as many, not DICT_4X4_50"),
])
def test_bad_layouts_are_refused_in_one_line(settings, message):
    with pytest.raises(ValueError, match=message):
        MarkerSheet(**settings)


def _caustic_photo(corners_px, tmp_path):
    """A .npy photo of the sheet whose receiver shows a caustic-like pattern, and the receiver's
    true corners in it."""
    page = SHEET.render(DPI).astype(np.float64) / 255 * 0.3  # the paper in ambient light
    size = page.shape[0]
    inner = int(round(SHEET.receiver_mm * PER_MM))
    start = (size - inner) // 2
    row, col = np.mgrid[0:inner, 0:inner] / inner
    page[start:start + inner, start:start + inner] = 0.4 + 0.5 * np.exp(-((col - 0.4) ** 2 + (row - 0.6) ** 2) / 0.02)
    src = np.float32([[-0.5, -0.5], [size - 0.5, -0.5], [size - 0.5, size - 0.5], [-0.5, size - 0.5]])
    h = cv2.getPerspectiveTransform(src, np.float32(corners_px)).astype(np.float64)
    photo = cv2.warpPerspective(page, h, (1300, 1100), flags=cv2.INTER_AREA, borderValue=0.05)
    np.save(tmp_path / "photo.npy", np.clip(cv2.GaussianBlur(photo, (0, 0), 1.0), 0.0, 1.0))
    half = SHEET.receiver_mm / 2
    receiver_mm = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
    page_px = np.c_[receiver_mm[:, 0] * PER_MM + size / 2 - 0.5, size / 2 - receiver_mm[:, 1] * PER_MM - 0.5]
    return tmp_path / "photo.npy", cv2.perspectiveTransform(page_px[None], h)[0]


def test_a_photo_located_by_its_markers_imports_as_with_its_true_corners(tmp_path):
    from framework.lab.photo_import import import_photo

    path, truth = _caustic_photo(VIEWS["oblique"], tmp_path)
    by_markers = import_photo(path, SHEET, 1.0, 128)
    by_corners = import_photo(path, truth.tolist(), 1.0, 128)
    error = np.linalg.norm(by_markers.image - by_corners.image) / np.linalg.norm(by_corners.image)
    assert error < 1e-3, error
    assert by_markers.steps[1].startswith("receiver corners from 12 of 12 markers (DICT_4X4_50)")


def test_data_photo_takes_the_sheets_layout_and_refuses_a_sheet_of_another_receiver(tmp_path):
    from experiments.apps.configs import app_config
    from framework.reconstruction.parts import Reconstruction

    path, _ = _caustic_photo(VIEWS["oblique"], tmp_path)
    SHEET.save(tmp_path / "sheet", dpi=DPI)
    base = ["data=photo", f"data.photo={path}", "data.volume=0.01", "receiver.resolution=64", "photons=20000",
            "height_field.resolution=32", "units.mm_per_unit=25"]
    Reconstruction.from_config(app_config("reconstruct", [*base, f"data.markers={tmp_path / 'sheet.json'}"]),
                               tmp_path).check(tmp_path, tmp_path / "run")
    MarkerSheet(receiver_mm=40.0).save(tmp_path / "small", dpi=DPI)
    with pytest.raises(ValueError, match=r"the sheet frames a 40 mm receiver but the scene's is 50 mm .*"
                                         r"sfc-markers --receiver-mm 50"):
        Reconstruction.from_config(app_config("reconstruct", [*base, f"data.markers={tmp_path / 'small.json'}"]),
                                   tmp_path).check(tmp_path, tmp_path / "run2")
    with pytest.raises(ValueError, match="data=photo needs either data.markers=.* not both"):
        Reconstruction.from_config(app_config("reconstruct", [*base, f"data.markers={tmp_path / 'sheet.json'}",
                                                              "data.corners=[[1,2],[3,4],[5,6],[7,8]]"]), tmp_path)
