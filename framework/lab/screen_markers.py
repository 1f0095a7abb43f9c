"""The screen found by its printed markers: a sheet of ArUco markers around the receiver square,
its layout saved beside it, and the receiver's corners in a photo from the markers detected there
(docs/photo_import.md, "Markers").

Screen coordinates are millimetres on the sheet, origin at the receiver's centre, x right and y
up as the camera's side of the sheet is printed; the receiver is the square |x|, |y| <= side / 2.
Every marker is a square of side ``marker_mm`` whose corners the detector returns in the order
top-left, top-right, bottom-right, bottom-left of the printed marker. The homography from screen
to photo is fitted to the detected markers' centres, the means of their four corners (RANSAC, then
least squares on the inliers, OpenCV): a blurred photo shows every marker smaller or larger by a
fraction of a pixel at each corner (measured: 0.3-0.8 px inward at 1-2.5 px of blur), which the
corners would pass to the fit and the centres cancel. The fit's standard errors are propagated to
the receiver's corners.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from framework.lab.photo_geometry import RECEIVER_CORNERS, project_points
from framework.lab.printables import aruco_dictionary, detector_image, load_layout, save_printable

__all__ = ["MarkerFit", "MarkerSheet", "detect_receiver"]

MIN_MARKERS = 3  # fewer than this (12 corners) leaves the homography to one side of the frame
_INLIER_SHARE = 0.1  # RANSAC's reprojection threshold: this share of a marker's side in the photo (at least 1 px)


@dataclass(frozen=True)
class MarkerSheet:
    """A printable ring of ArUco markers around the receiver square.

    Attributes:
        receiver_mm: The receiver's side (mm): 2 W in the scene's units times ``units.mm_per_unit``.
        marker_mm: Each marker's side (mm), its black border included.
        gap_mm: From the receiver's edge to the markers' inner edge (mm).
        per_side: Markers along each side of the ring, corners shared (4 (per_side - 1) in all).
        dictionary: The OpenCV ArUco dictionary, e.g. ``DICT_4X4_50``.
    """

    receiver_mm: float
    marker_mm: float = 6.0
    gap_mm: float = 2.0
    per_side: int = 4
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self) -> None:
        for key, value in (("receiver_mm", self.receiver_mm), ("marker_mm", self.marker_mm)):
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise ValueError(f"markers.{key}={value!r} must be a length > 0 in mm, e.g. 50")
        if not (isinstance(self.gap_mm, (int, float)) and self.gap_mm >= 0):
            raise ValueError(f"markers.gap_mm={self.gap_mm!r} must be a length >= 0 in mm")
        if not (isinstance(self.per_side, int) and self.per_side >= 2):
            raise ValueError(f"markers.per_side={self.per_side!r} must be a whole number >= 2")
        if len(self.centres()) > self.aruco().bytesList.shape[0]:
            raise ValueError(f"markers: {len(self.centres())} markers need a dictionary with as many, not "
                             f"{self.dictionary}; lower per_side or take e.g. DICT_4X4_100")

    def aruco(self):  # noqa: ANN201 (cv2.aruco.Dictionary)
        """OpenCV's dictionary of the sheet's markers (refused in one line if unknown)."""
        return aruco_dictionary(self.dictionary, "markers.dictionary")

    def check_frames(self, receiver_mm: float, where: str, why: str, fix: str) -> None:
        """Refuse a sheet whose receiver is not the scene's ``receiver_mm`` (to 0.1%), in one line:
        ``where``, the two sizes, ``why`` the scene's is that size, and ``fix``."""
        if abs(self.receiver_mm - receiver_mm) > 1e-3 * receiver_mm:
            raise ValueError(f"{where}: the sheet frames a {self.receiver_mm:g} mm receiver but the scene's is "
                             f"{receiver_mm:g} mm ({why}); {fix}")

    def centres(self) -> np.ndarray:
        """(k, 2) marker centres (mm), marker id = row: around the ring counter-clockwise from the
        bottom-left corner."""
        reach = self.receiver_mm / 2 + self.gap_mm + self.marker_mm / 2
        t = np.linspace(-reach, reach, self.per_side)[:-1]
        sides = [np.stack([t, np.full_like(t, -reach)], 1), np.stack([np.full_like(t, reach), t], 1),
                 np.stack([-t, np.full_like(t, reach)], 1), np.stack([np.full_like(t, -reach), -t], 1)]
        return np.concatenate(sides)

    def corners(self) -> np.ndarray:
        """(k, 4, 2) every marker's corners (mm) in the detector's order."""
        h = self.marker_mm / 2
        offsets = np.array([[-h, h], [h, h], [h, -h], [-h, -h]])
        return self.centres()[:, None, :] + offsets[None]

    def page_mm(self) -> float:
        """The printed page's side (mm): the ring and a margin of one marker."""
        return self.receiver_mm + 2 * (self.gap_mm + self.marker_mm) + 2 * self.marker_mm

    def render(self, dpi: float = 600.0) -> np.ndarray:
        """The sheet to print at ``dpi`` dots per inch: (P, P) uint8, white page, black markers,
        the receiver square left white (row 0 = the page's top, +y)."""
        import cv2

        per_mm = dpi / 25.4
        size = int(round(self.page_mm() * per_mm))
        page = np.full((size, size), 255, np.uint8)
        dictionary = self.aruco()
        side = int(round(self.marker_mm * per_mm))
        for marker_id, (x, y) in enumerate(self.centres()):
            col = int(round((x - self.marker_mm / 2) * per_mm + size / 2))
            row = int(round(size / 2 - (y + self.marker_mm / 2) * per_mm))
            page[row:row + side, col:col + side] = cv2.aruco.generateImageMarker(dictionary, marker_id, side)
        return page

    def save(self, path: str | Path, dpi: float = 600.0) -> tuple[Path, Path]:
        """The sheet as a PNG that prints at its size (``dpi`` in the file) and its layout beside it
        (the same name, ``.json``); returns both paths."""
        return save_printable(self.render(dpi), asdict(self), path, dpi)

    @classmethod
    def load(cls, path: str | Path) -> MarkerSheet:
        """The layout a :meth:`save` wrote (``.json``), refused in one line if it is not one."""
        return load_layout(cls, path, "a marker layout written by sfc-markers (the .json beside the sheet's PNG)")


@dataclass(frozen=True)
class MarkerFit:
    """The receiver located in a photo by its markers.

    Attributes:
        corners: (4, 2) the receiver's corners [col, row] in photo pixels, in the order
            bottom-left, bottom-right, top-right, top-left.
        corner_std: (4,) each corner's standard error (px), from the fit's residuals.
        rms_px: Root-mean-square reprojection error of the inlying markers' centres (px).
        found: Marker ids detected and used, ascending.
        rejected: Marker ids detected but left out by RANSAC.
    """

    corners: np.ndarray
    corner_std: np.ndarray
    rms_px: float
    found: tuple[int, ...]
    rejected: tuple[int, ...]

    def describe(self, sheet: MarkerSheet) -> str:
        """One line for the import's steps."""
        total = len(sheet.centres())
        ids = ", ".join(map(str, self.rejected))
        left = f"; {len(self.rejected)} rejected as outliers ({ids})" if self.rejected else ""
        return (f"receiver corners from {len(self.found)} of {total} markers ({sheet.dictionary}): reprojection rms "
                f"{self.rms_px:.3f} px, corners to +-{self.corner_std.max():.3f} px{left}")


def _corner_errors(h: np.ndarray, screen: np.ndarray, residual: np.ndarray, receiver: np.ndarray) -> np.ndarray:
    """(4,) standard errors (px) of the receiver's corners through the homography h fitted to the
    screen points with ``residual`` (k, 2) photo pixels: the residual variance propagated by the
    fit's linearisation in h's eight free entries."""
    params = (h / h[2, 2]).ravel()[:8]
    steps = 1e-7 * np.maximum(np.abs(params), 1e-3)

    def jacobian(points: np.ndarray) -> np.ndarray:
        """d(projected points, flattened) / d(params), by central differences."""
        def project(p: np.ndarray) -> np.ndarray:
            return np.stack(project_points(np.append(p, 1.0).reshape(3, 3), points[:, 0], points[:, 1]), 1).ravel()
        return np.stack([(project(params + e) - project(params - e)) / (2 * step)
                         for e, step in zip(np.diag(steps), steps)], axis=1)

    jac = jacobian(screen)
    dof = max(residual.size - 8, 1)
    cov = float(np.sum(residual ** 2)) / dof * np.linalg.pinv(jac.T @ jac)
    corner_jac = jacobian(receiver)
    var = np.einsum("ij,jk,ik->i", corner_jac, cov, corner_jac).reshape(4, 2)
    return np.sqrt(var.sum(axis=1))


def detect_receiver(values: np.ndarray, sheet: MarkerSheet, name: str = "photo") -> MarkerFit:
    """The receiver's corners in a photo (H, W[, 3], linear values) from the markers of ``sheet``
    seen there. ValueError in one line when fewer than MIN_MARKERS are found (which ones were,
    and what to check)."""
    import cv2

    parameters = cv2.aruco.DetectorParameters()
    parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_CONTOUR
    found, ids, _ = cv2.aruco.ArucoDetector(sheet.aruco(), parameters).detectMarkers(detector_image(values))
    total = len(sheet.centres())
    known = {int(i): k for k, i in enumerate(ids.ravel()) if int(i) < total} if ids is not None else {}
    if len(known) < MIN_MARKERS:
        seen = ", ".join(map(str, sorted(known))) or "none"
        raise ValueError(f"{name}: {len(known)} of the {total} markers of {sheet.dictionary} found (ids {seen}), at "
                         f"least {MIN_MARKERS} needed; the sheet's frame must be in the photo, in focus, lit and free "
                         "of glare, and printed from the layout given in data.markers; or type data.corners")
    order = sorted(known)
    quads = np.stack([found[known[i]].reshape(4, 2) for i in order]).astype(np.float64)
    screen, photo = sheet.centres()[order], quads.mean(axis=1)
    side_px = float(np.median(np.linalg.norm(quads - np.roll(quads, 1, axis=1), axis=2)))
    h, inliers = cv2.findHomography(screen, photo, cv2.RANSAC, max(1.0, _INLIER_SHARE * side_px))
    keep = np.zeros(len(order), bool) if h is None else inliers.ravel().astype(bool)
    used = [i for i, k in zip(order, keep) if k]
    if len(used) < MIN_MARKERS:
        raise ValueError(f"{name}: only {len(used)} of the {len(order)} markers found agree on one view of a flat "
                         "sheet; check that data.markers names the layout the sheet was printed from")
    screen_in, photo_in = screen[keep], photo[keep]
    h, _ = cv2.findHomography(screen_in, photo_in, 0)
    receiver = np.asarray(RECEIVER_CORNERS) * (sheet.receiver_mm / 2)
    corners = cv2.perspectiveTransform(receiver[None], h)[0]
    residual = cv2.perspectiveTransform(screen_in[None], h)[0] - photo_in
    return MarkerFit(corners=corners, corner_std=_corner_errors(h, screen_in, residual, receiver),
                     rms_px=float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1)))), found=tuple(used),
                     rejected=tuple(i for i, k in zip(order, keep) if not k))
