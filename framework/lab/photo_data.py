"""``data=photo``: a camera photo of the screen as the data of a reconstruction.

The photo goes through framework/lab/photo_import.py (bit depth, black level, dark frame, inverse response,
flat field, saturation, rectification onto the receiver; docs/photo_import.md). What comes out
is irradiance up to the flat field's shape and an unknown scale:

- ``flat_kind: substrate`` (the flat-field photo shows the bare substrate's caustic, taken with
  the same light and screen): photo / flat is the print's irradiance relative to the bare
  substrate's, so it is multiplied by the model's caustic of flat glass;
- ``flat_kind: uniform`` (the flat shows the screen evenly lit): photo / flat is the irradiance;
- no flat: the photo is taken as the irradiance (vignetting and screen non-uniformity stay in).

``brightness: energy`` then scales it so that the weighted power equals the model's power on
the receiver with flat glass (framework/core/data.py); saturated pixels carry weight 0 in the data
term. The import's steps and a figure are written to the run directory (photo_import.json,
photo_import.png).

With ``repeat`` (a second exposure of the same print, same settings) the data are the mean of the
two, and ``delta: auto`` estimates their noise level from the difference: the noise of the mean,
(e1 - e2) / 2, has the spread of (e1 + e2) / 2's noise, so delta = ||W (i1 - i2)|| / ||W (i1 + i2)||
over the pixels the fit uses (docs/photo_import.md, "The noise level").
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import torch

from framework.core.contracts.data_source import DataRequest, PrintFacts
from framework.core.data import ReconstructionData
from framework.data.sources import KnownPrint, file_setting
from framework.files.image_io import resolve_path
from framework.lab.lens import LensModel
from framework.lab.screen_markers import MarkerSheet
from framework.lab.photo_figure import save_photo_figure
from framework.lab.photo_import import PhotoImport, import_photo
from operators.values import is_number

__all__ = ["PhotoData", "two_exposure_delta"]

FLAT_KINDS = ("substrate", "uniform")


def two_exposure_delta(first: torch.Tensor, second: torch.Tensor, weights: torch.Tensor) -> float:
    """The relative noise level of the mean of two exposures of one scene (same shape), from their
    difference: ||W (first - second)|| / ||W (first + second)||."""
    w = weights.double()
    total = float(torch.linalg.vector_norm(w * (first + second)))
    if not total > 0:
        raise ValueError("data.repeat: the two exposures hold no light where the fit looks; check the photos")
    return float(torch.linalg.vector_norm(w * (first - second))) / total


class PhotoData(KnownPrint):
    """A camera photo of the caustic on the screen (``data=photo``).

    Args:
        photo: Path of the photo: a camera RAW file (.dng, .cr2, .nef, ...), 8/16-bit PNG/TIFF
            (grey or RGB) or a linear .npy.
        corners: The receiver's corners in the photo, [[col, row] x 4] in pixels (row 0 at the
            top), in the order bottom-left, bottom-right, top-right, top-left of the receiver.
        markers: Instead of ``corners``: the layout (.json) of the marker sheet printed around the
            receiver (sfc-markers); each photo is located by the markers it shows.
        lens: The camera's distortion (.json of sfc-lens calibrate), undone on every photo first;
            None: an ideal lens.
        pixel_centre: The coordinate of the first pixel's centre in ``corners``: 0 (NumPy, OpenCV,
            scikit-image) or 0.5 (GIMP, Pillow, Inkscape: the first pixel spans [0, 1]).
        repeat: A second exposure of the same print with the same settings, or None. With it the
            data are the mean of the two and ``delta: auto`` is estimated from their difference.
        channel, bit_depth, response, gamma, black_level, dark, flat, saturation, supersample:
            The import's settings (framework/lab/photo_import.py, import_photo).
        flat_kind: What the flat-field photo shows: ``substrate`` or ``uniform`` (module docstring).
        mask, volume, delta, brightness, mask_threshold, mask_dilation: What is known about the
            print (framework/data/sources.py, KnownPrint); ``delta: auto`` needs ``repeat``.
    """

    def __init__(self, photo: str | None = None, corners: list[list[float]] | None = None,
                 markers: str | None = None, lens: str | None = None, pixel_centre: float = 0.0,
                 repeat: str | None = None, channel: str = "grey",
                 bit_depth: int | None = None, response: str = "linear", gamma: float = 2.2,
                 black_level: float = 0.0, dark: str | None = None, flat: str | None = None,
                 flat_kind: str = "substrate", saturation: float = 0.98, supersample: int = 4,
                 mask: str | None = None, volume: float | str | None = None, delta: float | str = 0.05,
                 brightness: str = "energy", mask_threshold: float = 1e-3, mask_dilation: float = 0.05) -> None:
        if not photo:
            raise ValueError("data=photo needs data.photo=<photo: a camera RAW file, .png/.tif or .npy>")
        if (corners is None) == (markers is None):
            raise ValueError("data=photo needs either data.markers=<the marker sheet's layout .json, sfc-markers> or "
                             "data.corners=[[col,row],[col,row],[col,row],[col,row]]: the receiver's bottom-left, "
                             "bottom-right, top-right and top-left corners in the photo" + (
                                 "; not both" if markers is not None else ""))
        if flat_kind not in FLAT_KINDS:
            raise ValueError(f"data.flat_kind={flat_kind!r}; use {' or '.join(FLAT_KINDS)}")
        if not is_number(pixel_centre) or pixel_centre not in (0, 0.5):
            raise ValueError(f"data.pixel_centre={pixel_centre!r} must be 0 (the first pixel's centre at 0: NumPy, "
                             "OpenCV) or 0.5 (GIMP, Pillow, Inkscape)")
        self.estimate_delta = delta == "auto"
        if self.estimate_delta and not repeat:
            raise ValueError("data.delta=auto needs data.repeat=<a second exposure of the same print with the same "
                             "settings>, from which the noise level is estimated; or give data.delta=<number>")
        super().__init__(mask, volume, 0.05 if self.estimate_delta else delta, brightness, mask_threshold,
                         mask_dilation)
        for key, value in (("photo", photo), ("repeat", repeat), ("dark", dark), ("flat", flat), ("markers", markers),
                           ("lens", lens)):
            file_setting(key, value)
        self.photo, self.repeat, self.flat, self.flat_kind, self.dark = str(photo), repeat, flat, flat_kind, dark
        self.corners, self.markers, self.lens, self.pixel_centre = corners, markers, lens, float(pixel_centre)
        self.settings = {"channel": channel, "bit_depth": bit_depth, "response": response, "gamma": gamma,
                         "black_level": black_level, "saturation": saturation, "supersample": supersample}
        self._imported: tuple[Any, list[PhotoImport]] | None = None

    def _imports(self, request: DataRequest) -> list[PhotoImport]:
        """The photo (and the repeat exposure) imported onto the receiver, once per receiver."""
        operator = request.operator
        channels, n = operator.output_shape[0], operator.output_shape[-1]
        if channels != 1:
            raise ValueError(f"data=photo gives one channel but the scene has {channels} wavelengths; "
                             "set wavelengths=[<the filter's wavelength>], e.g. wavelengths=[0.525]")
        half_width = float(operator.scene.receiver.half_width)
        key = (n, half_width, str(request.base_dir))
        if self._imported is None or self._imported[0] != key:
            path = lambda p: None if p is None else resolve_path(str(p), request.base_dir)  # noqa: E731
            photos = [self.photo] + ([self.repeat] if self.repeat else [])
            lens = None if self.lens is None else LensModel.load(path(self.lens))
            locator = self._locator(request)
            imported = [import_photo(path(p), locator, half_width, n, dark=path(self.dark), flat=path(self.flat),
                                     lens=lens, **self.settings) for p in photos]
            self._imported = (key, imported)
        return self._imported[1]

    def _locator(self, request: DataRequest) -> Any:
        """What locates the receiver in each photo: the marker sheet (its receiver checked against the
        scene's), or the typed corners."""
        if self.markers is None:
            return (self._corners() - self.pixel_centre).tolist()
        sheet = MarkerSheet.load(resolve_path(self.markers, request.base_dir))
        side_mm = 2 * float(request.operator.scene.receiver.half_width) * request.mm_per_unit
        sheet.check_frames(side_mm, f"data.markers={self.markers}", "2 receiver.half_width x units.mm_per_unit",
                           f"print a sheet with sfc-markers --receiver-mm {side_mm:g}, or set the receiver to the "
                           "sheet's")
        return sheet

    def _corners(self) -> Any:
        """The corners as given, refused in one line when they are not four pairs of numbers."""
        try:
            return np.array(self.corners, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"data.corners={self.corners!r} must be four [col, row] photo pixel coordinates "
                             "(quote the whole override in zsh: 'data.corners=[[c,r],[c,r],[c,r],[c,r]]')") from None

    def check(self, request: DataRequest) -> PrintFacts:
        """Import the photos (no render): every file, setting and the corners are checked."""
        self._imports(request)
        return super().check(request)

    def load(self, request: DataRequest) -> ReconstructionData:
        """Import the photo onto the reconstruction's receiver; scale it; estimate the noise level
        from the repeat exposure (delta: auto); write the import's record."""
        imported = self._imports(request)
        first = imported[0]
        images = [torch.from_numpy(i.image).double() for i in imported]
        weights = torch.from_numpy(np.prod([i.weights for i in imported], axis=0)).double()
        steps = list(first.steps)
        factor = torch.ones_like(images[0])
        flat_render = None
        if (self.flat is not None and self.flat_kind == "substrate") or self.brightness == "energy":
            flat_render = self.bare_substrate_caustic(request)
        if self.flat is not None and self.flat_kind == "substrate":
            factor = flat_render / float(flat_render.mean())
            steps.append("multiplied by the model's caustic of the bare substrate (flat_kind: substrate)")
        target = factor * sum(images) / len(images)
        delta = self.delta
        if len(images) == 2:
            estimate = two_exposure_delta(factor * images[0], factor * images[1], weights)
            steps.append(f"mean of {first.path.name} and the repeat exposure {imported[1].path.name}; their noise "
                         f"level estimated from the difference: delta = {estimate:.4f}"
                         + ("" if self.estimate_delta else f" (data.delta={self.delta:g} used)"))
            if self.estimate_delta:
                if not 0 < estimate < 0.5:
                    raise ValueError(f"data.repeat: the two exposures differ by {estimate:.3g} of their norm; give "
                                     "two exposures of one print with one setting, or data.delta=<number>")
                delta = estimate
        if self.brightness == "energy":
            scale = float((weights * flat_render).sum()) / float((weights * target).sum())
            target = target * scale
            steps.append(f"scaled by {scale:.4g} to the model's power on the receiver with flat glass")
        left_out = {k: max(i.left_out.get(k, 0) for i in imported) for k in first.left_out}
        if request.output_dir is not None:
            request.output_dir.mkdir(parents=True, exist_ok=True)
            save_photo_figure(request.output_dir / "photo_import.png", first)
            record = {"steps": steps, "corners": first.corners.tolist(), "homography": first.homography.tolist(),
                      "left_out": left_out, "weighted_out": int((weights == 0).sum()), "delta": delta,
                      "delta_estimated": self.estimate_delta}
            (request.output_dir / "photo_import.json").write_text(json.dumps(record, indent=2))
        for step in steps:
            print(f"photo: {step}", flush=True)
        return ReconstructionData(target=target, mask=self.printed_area(request), volume=self.deposited_volume(request),
                                  delta=delta, weights=weights, left_out=left_out, source=str(first.path.resolve()))
