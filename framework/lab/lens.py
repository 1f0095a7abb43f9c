"""The camera lens's distortion: calibrated from photos of a ChArUco board, saved once, and undone
on every photo before the receiver is located and rectified (docs/photo_import.md, "Lens
distortion").

The model is OpenCV's pinhole camera with radial and tangential distortion (k1, k2, p1, p2, k3):
a point at normalised coordinates (x, y) = K^-1 (u, v, 1) of an ideal lens is seen at
x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2), likewise for y. Undoing it
resamples the photo onto the ideal lens's pixel grid with the same camera matrix, so pixel
coordinates keep their meaning (bilinear interpolation, OpenCV's remap).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from framework.lab.printables import aruco_dictionary, detector_image, load_layout, read_layout, save_printable

__all__ = ["CharucoBoard", "LensModel", "calibrate_lens"]

MIN_VIEWS = 3  # photos of the board with enough corners: fewer cannot tell focal length from distortion
MIN_CORNERS = 12  # chessboard corners a photo must show to count as a view


@dataclass(frozen=True)
class CharucoBoard:
    """A ChArUco calibration board: a chessboard whose white squares hold ArUco markers.

    Attributes:
        squares_x, squares_y: Squares across and down.
        square_mm: A square's side (mm).
        marker_mm: A marker's side inside its square (mm).
        dictionary: The OpenCV ArUco dictionary.
    """

    squares_x: int = 9
    squares_y: int = 6
    square_mm: float = 10.0
    marker_mm: float = 7.0
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self) -> None:
        if not (isinstance(self.squares_x, int) and isinstance(self.squares_y, int) and min(self.squares_x,
                                                                                              self.squares_y) >= 3):
            raise ValueError(f"board squares {self.squares_x} x {self.squares_y} must be whole numbers >= 3")
        if not 0 < self.marker_mm < self.square_mm:
            raise ValueError(f"board marker_mm={self.marker_mm!r} must lie in (0, square_mm={self.square_mm!r})")
        aruco_dictionary(self.dictionary, "board dictionary")

    def board(self):  # noqa: ANN201 (cv2.aruco.CharucoBoard)
        """OpenCV's board, lengths in mm."""
        import cv2

        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_mm, self.marker_mm,
                                      aruco_dictionary(self.dictionary, "board dictionary"))

    def render(self, dpi: float = 600.0) -> np.ndarray:
        """The board to print at ``dpi``: (rows, cols) uint8 with a white margin of one square (the
        detector needs it around the outer black squares)."""
        per_mm = dpi / 25.4
        margin = int(round(self.square_mm * per_mm))
        size = (int(round(self.squares_x * self.square_mm * per_mm)) + 2 * margin,
                int(round(self.squares_y * self.square_mm * per_mm)) + 2 * margin)
        return self.board().generateImage(size, marginSize=margin, borderBits=1)

    def save(self, path: str | Path, dpi: float = 600.0) -> tuple[Path, Path]:
        """The board's PNG (``dpi`` in the file) and its description beside it (.json)."""
        return save_printable(self.render(dpi), asdict(self), path, dpi)

    @classmethod
    def load(cls, path: str | Path) -> CharucoBoard:
        """A board :meth:`save` described."""
        return load_layout(cls, path, "a ChArUco board written by sfc-lens board")

    def detect(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The board's chessboard corners seen in a photo (H, W[, 3], linear values): (k, 2) photo
        pixels and (k, 3) board points (mm, z = 0); k = 0 when the board is not seen."""
        import cv2

        board = self.board()
        corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(detector_image(values))
        if ids is None or len(ids) == 0:
            return np.zeros((0, 2)), np.zeros((0, 3))
        points = np.asarray(board.getChessboardCorners(), dtype=np.float64)[ids.ravel()]
        return corners.reshape(-1, 2).astype(np.float64), points


@dataclass(frozen=True)
class LensModel:
    """A calibrated camera: ``camera_matrix`` (3 x 3, pixels), ``distortion`` (k1, k2, p1, p2,
    k3), the ``image_size`` (width, height) it holds for, the calibration's reprojection ``rms_px``
    and the number of ``views`` it came from."""

    camera_matrix: tuple[tuple[float, ...], ...]
    distortion: tuple[float, ...]
    image_size: tuple[int, int]
    rms_px: float
    views: int

    def save(self, path: str | Path) -> Path:
        """The model as JSON."""
        Path(path).write_text(json.dumps(asdict(self), indent=2))
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> LensModel:
        """A model :meth:`save` wrote."""
        values = read_layout(path, "a lens calibration written by sfc-lens calibrate")
        try:
            return cls(camera_matrix=tuple(tuple(float(v) for v in row) for row in values["camera_matrix"]),
                       distortion=tuple(float(v) for v in values["distortion"]),
                       image_size=(int(values["image_size"][0]), int(values["image_size"][1])),
                       rms_px=float(values["rms_px"]), views=int(values["views"]))
        except (KeyError, TypeError, ValueError, IndexError) as error:
            raise ValueError(f"{path} is not a lens calibration written by sfc-lens calibrate ({error})") from None

    def describe(self) -> str:
        """The calibration in one line."""
        return (f"k1, k2, p1, p2, k3 = {', '.join(f'{k:.4g}' for k in self.distortion)}; calibrated on {self.views} "
                f"photos, rms {self.rms_px:.3f} px")

    def undistort(self, values: np.ndarray, name: str = "photo") -> np.ndarray:
        """``values`` (H, W[, 3]) resampled as the ideal lens would have seen them (same shape);
        ValueError in one line for a photo of another size than the calibration's."""
        import cv2

        height, width = values.shape[:2]
        if (width, height) != tuple(self.image_size):
            raise ValueError(f"{name} is {width} x {height} px but the lens was calibrated on {self.image_size[0]} x "
                             f"{self.image_size[1]} px photos; calibrate it again at this size (sfc-lens calibrate), "
                             "or take the photo at the calibrated one")
        map_x, map_y = _undistortion_maps(self.camera_matrix, self.distortion, (width, height))
        out = cv2.remap(values.astype(np.float64), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                        borderValue=0.0)
        return out.reshape(values.shape)

    def displacement(self, points: np.ndarray) -> np.ndarray:
        """(k, 2) where the lens shows ideal pixel positions ``points`` (k, 2): the distortion map."""
        import cv2

        k = np.asarray(self.camera_matrix, dtype=np.float64)
        ideal = cv2.undistortPoints(points.reshape(-1, 1, 2).astype(np.float64), k, np.zeros(5))
        seen, _ = cv2.projectPoints(np.c_[ideal.reshape(-1, 2), np.ones(len(points))], np.zeros(3), np.zeros(3), k,
                                    np.asarray(self.distortion))
        return seen.reshape(-1, 2)


def calibrate_lens(photos: Sequence[np.ndarray], board: CharucoBoard, names: Sequence[str] | None = None) -> LensModel:
    """The lens from photos (each (H, W[, 3]) linear values, one size) of ``board`` in several
    poses. ValueError in one line with fewer than MIN_VIEWS usable photos (naming the others)."""
    import cv2

    names = list(names or [f"photo {k}" for k in range(len(photos))])
    sizes = {p.shape[:2] for p in photos}
    if len(sizes) != 1:
        raise ValueError(f"the calibration photos have sizes {sorted(sizes)}; take them all at one size")
    object_points, image_points, unused = [], [], []
    for photo, name in zip(photos, names):
        seen, points = board.detect(photo)
        if len(seen) < MIN_CORNERS:
            unused.append(f"{name} ({len(seen)} corners)")
            continue
        image_points.append(seen.astype(np.float32))
        object_points.append(points.astype(np.float32))
    if len(image_points) < MIN_VIEWS:
        raise ValueError(f"{len(image_points)} photos show the board with at least {MIN_CORNERS} corners, "
                         f"{MIN_VIEWS} needed (unused: {', '.join(unused) or 'none'}); photograph the whole board "
                         "tilted a different way each time, filling the frame")
    height, width = next(iter(sizes))
    # k3 stays 0: a bench's macro lens bends as k1, k2 describe, and a free k3 fitted to boards that
    # do not reach the frame's corners throws the corners out by tens of pixels
    rms, k, dist, _, _ = cv2.calibrateCamera(object_points, image_points, (width, height), None, None,
                                             flags=cv2.CALIB_FIX_K3)
    return LensModel(camera_matrix=tuple(tuple(float(v) for v in row) for row in k),
                     distortion=tuple(float(v) for v in np.ravel(dist)[:5]), image_size=(width, height),
                     rms_px=float(rms), views=len(image_points))


@lru_cache(maxsize=2)
def _undistortion_maps(camera_matrix: tuple[tuple[float, ...], ...], distortion: tuple[float, ...],
                       size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's remap tables (H, W) float32 from the ideal lens's pixels to the photo's, kept for
    the next frame of the same lens and size (a photo's import undoes the lens on the photo, its
    saturation, the dark frame and the flat field)."""
    import cv2

    k = np.asarray(camera_matrix, dtype=np.float64)
    return cv2.initUndistortRectifyMap(k, np.asarray(distortion), None, k, size, cv2.CV_32FC1)
