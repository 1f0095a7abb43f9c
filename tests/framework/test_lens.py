"""The camera lens's distortion (framework/lab/lens.py): calibrated from synthetic photos of a
ChArUco board through a known lens, and undone so that the marker sheet's photo is one flat view."""

from __future__ import annotations

import numpy as np
import pytest

from framework.lab.lens import CharucoBoard, LensModel, calibrate_lens
from framework.lab.photo_synthesis import camera_view
from framework.lab.screen_markers import MarkerSheet, detect_receiver

SIZE = (800, 600)
K = np.array([[900.0, 0.0, 400.0], [0.0, 900.0, 300.0], [0.0, 0.0, 1.0]])
BARREL = (-0.05, 0.01, 0.0, 0.0, 0.0)  # 1.4% at the frame's corners, up to 5.8 px
POSES = [((0.3, 0.0, 0.0), (0, 0, 130)), ((-0.3, 0.1, 0.0), (5, -5, 140)), ((0.0, 0.35, 0.1), (-5, 0, 125)),
         ((0.1, -0.35, -0.1), (0, 5, 130)), ((0.25, 0.25, 0.3), (0, 0, 120)), ((-0.2, -0.25, -0.2), (3, 3, 145))]
DPI = 254.0


def _board_photos(board: CharucoBoard, views: int = len(POSES)) -> list[np.ndarray]:
    page = board.render(DPI).astype(np.float64) / 255
    return [0.1 + 0.8 * camera_view(page, 25.4 / DPI, K, BARREL, r, t, SIZE, outside=1.0) for r, t in POSES[:views]]


def _grid(step: int = 20) -> np.ndarray:
    cols, rows = np.meshgrid(np.arange(0, SIZE[0], step, dtype=float), np.arange(0, SIZE[1], step, dtype=float))
    return np.stack([cols.ravel(), rows.ravel()], axis=1)


@pytest.fixture(scope="module")
def calibrated() -> LensModel:
    board = CharucoBoard()
    return calibrate_lens(_board_photos(board), board)


def test_the_distortion_is_recovered_from_six_photos_of_the_board(calibrated):
    truth = LensModel(tuple(map(tuple, K)), BARREL, SIZE, 0.0, 0)
    grid = _grid()
    shift = np.linalg.norm(truth.displacement(grid) - grid, axis=1)
    error = np.linalg.norm(calibrated.displacement(grid) - truth.displacement(grid), axis=1)
    assert shift.max() > 5.0  # what there is to recover
    assert error.max() < 0.35, error.max()  # measured 0.24 px, at the frame's corners
    assert calibrated.views == 6 and calibrated.rms_px < 0.2
    np.testing.assert_allclose(np.asarray(calibrated.camera_matrix), K, atol=2.0)


def test_undone_distortion_makes_the_marker_sheet_one_flat_view_again(calibrated, tmp_path):
    sheet = MarkerSheet(receiver_mm=50.0)
    page = 0.2 + 0.7 * sheet.render(DPI).astype(np.float64) / 255
    photo = camera_view(page, 25.4 / DPI, K, BARREL, (0.2, -0.15, 0.05), (0, 0, 95), SIZE, outside=0.05)
    bent = detect_receiver(photo, sheet)
    straight = detect_receiver(calibrated.undistort(photo), sheet)
    # measured: reprojection rms 0.46 px bent, 0.09 px straight (0.06 px for the ideal lens)
    assert bent.rms_px > 3 * straight.rms_px and straight.rms_px < 0.15, (bent.rms_px, straight.rms_px)
    # the receiver's corners where the ideal lens sees them: 1.3-2.7 px off bent, 0.01-0.15 px straight
    truth = detect_receiver(camera_view(page, 25.4 / DPI, K, (0.0,) * 5, (0.2, -0.15, 0.05), (0, 0, 95), SIZE,
                                        outside=0.05), sheet)
    assert np.linalg.norm(bent.corners - truth.corners, axis=1).max() > 1.0
    assert np.linalg.norm(straight.corners - truth.corners, axis=1).max() < 0.3


def test_lens_errors_are_one_line(calibrated, tmp_path):
    with pytest.raises(ValueError, match=r"photo x.dng is 640 x 480 px but the lens was calibrated on 800 x 600 px"):
        calibrated.undistort(np.zeros((480, 640)), "photo x.dng")
    board = CharucoBoard()
    blank = [np.full((SIZE[1], SIZE[0]), 0.5)] * 2
    with pytest.raises(ValueError, match=r"2 photos show the board with at least 12 corners, 3 needed \(unused: "
                                         r"c.png \(0 corners\), d.png \(0 corners\)\)"):
        calibrate_lens([*_board_photos(board, 2), *blank], board, ["a.png", "b.png", "c.png", "d.png"])
    (tmp_path / "lens.json").write_text('{"camera_matrix": 3}')
    with pytest.raises(ValueError, match="is not a lens calibration written by sfc-lens calibrate"):
        LensModel.load(tmp_path / "lens.json")
    calibrated.save(tmp_path / "good.json")
    assert LensModel.load(tmp_path / "good.json") == calibrated


def test_sfc_lens_writes_a_board_and_calibrates_from_its_photos(tmp_path, capsys):
    from experiments.apps.lens import main

    main(["board", "--dpi", str(DPI), "--out", str(tmp_path / "charuco")])
    board = CharucoBoard.load(tmp_path / "charuco.json")
    paths = []
    for k, photo in enumerate(_board_photos(board, 4)):
        paths.append(str(tmp_path / f"shot{k}.npy"))
        np.save(paths[-1], np.clip(photo, 0.0, 1.0))
    main(["calibrate", "--board", str(tmp_path / "charuco.json"), *paths, "--out", str(tmp_path / "lens.json")])
    assert "4 of 4 photos used" in capsys.readouterr().out
    assert LensModel.load(tmp_path / "lens.json").views == 4
