"""A synthetic lab bench: the screen framed by the marker sheet, an irradiance on its receiver,
photographed obliquely through a lens with distortion and vignetting, with noise; and the ChArUco
board photographed by the same camera. For tests and studies of the photo import against a known
truth (docs/photo_import.md, "A synthetic bench")."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from framework.lab.lens import CharucoBoard
from framework.lab.photo_synthesis import camera_view, vignetting_field
from framework.lab.screen_markers import MarkerSheet

__all__ = ["SyntheticBench"]

# The board tilted four ways toward the frame's corners and twice in its middle: (Rodrigues vector,
# translation mm) for camera_view.
BOARD_POSES = (((0.3, 0.0, 0.0), (-35.0, -25.0, 250.0)), ((-0.3, 0.1, 0.0), (35.0, -25.0, 260.0)),
               ((0.0, 0.35, 0.1), (-35.0, 25.0, 245.0)), ((0.1, -0.35, -0.1), (35.0, 25.0, 250.0)),
               ((0.25, 0.25, 0.3), (0.0, 0.0, 240.0)), ((-0.2, -0.25, -0.2), (0.0, 0.0, 230.0)))


@dataclass(frozen=True)
class SyntheticBench:
    """The camera and the screen of a bench.

    Attributes:
        sheet: The marker sheet around the receiver.
        size: The photos' (width, height), pixels.
        camera_matrix: (3, 3) pixels.
        distortion: OpenCV's (k1, k2, p1, p2, k3) of the lens the photos are made with.
        pose: (Rodrigues vector, translation mm) of the screen seen by the camera.
        vignetting: The light's fall-off at the frame's corners (vignetting_field).
        per_mm: Pixels a millimetre of the screen's page (a whole number: every marker edge and the
            receiver's on a page pixel edge).
        paper: The paper's brightness around the receiver in the caustic's photo.
    """

    sheet: MarkerSheet = field(default_factory=lambda: MarkerSheet(receiver_mm=50.0))
    size: tuple[int, int] = (2000, 1500)
    camera_matrix: tuple[tuple[float, ...], ...] = ((2800.0, 0.0, 1000.0), (0.0, 2800.0, 750.0), (0.0, 0.0, 1.0))
    distortion: tuple[float, ...] = (-0.05, 0.0, 0.0, 0.0, 0.0)  # 0.9% barrel at the frame's corners
    pose: tuple[tuple[float, float, float], tuple[float, float, float]] = ((0.15, -0.1, 0.05), (1.0, -2.0, 150.0))
    vignetting: float = 0.25
    per_mm: float = 16.0
    paper: float = 0.35

    def receiver_pixels(self) -> int:
        """The receiver's side on the page (pixels)."""
        return int(round(self.sheet.receiver_mm * self.per_mm))

    def page(self, irradiance: np.ndarray | None, lit: float = 0.6) -> np.ndarray:
        """The screen as the camera sees it: the sheet, its markers black, and in the receiver
        ``irradiance`` ((R, R) with R = :meth:`receiver_pixels`, row 0 = the receiver's top, +y)
        with the paper at ``paper`` around it; None: the screen evenly lit at ``lit`` (a flat
        field)."""
        page = self.sheet.render(self.per_mm * 25.4).astype(np.float64) / 255
        if irradiance is None:
            return lit * page
        inner = self.receiver_pixels()
        if np.shape(irradiance) != (inner, inner):
            raise ValueError(f"the receiver's irradiance must be {inner} x {inner} page pixels, got "
                             f"{np.shape(irradiance)}")
        page = self.paper * page
        start = (page.shape[0] - inner) // 2
        page[start:start + inner, start:start + inner] = irradiance
        return page

    def photograph(self, page: np.ndarray, noise: float, seed: int, distortion: bool = True) -> np.ndarray:
        """The page photographed: (H, W) linear values in [0, 1] with the bench's lens (its
        distortion unless ``distortion`` is False) and vignetting, and Gaussian noise of ``noise``
        (fraction of full scale, seeded)."""
        lens = self.distortion if distortion else (0.0,) * 5
        seen = camera_view(page, 1.0 / self.per_mm, np.asarray(self.camera_matrix), lens, *self.pose, self.size,
                           outside=0.02)
        seen = seen * vignetting_field(seen.shape, self.vignetting)
        return np.clip(seen + noise * np.random.default_rng(seed).standard_normal(seen.shape), 0.0, 1.0)

    def board_photos(self, board: CharucoBoard) -> list[np.ndarray]:
        """The ChArUco board photographed by the bench's camera in :data:`BOARD_POSES`."""
        dpi = 254.0
        page = board.render(dpi).astype(np.float64) / 255
        return [0.1 + 0.8 * camera_view(page, 25.4 / dpi, np.asarray(self.camera_matrix), self.distortion, rotation,
                                        translation, self.size, outside=1.0, supersample=1)
                for rotation, translation in BOARD_POSES]
