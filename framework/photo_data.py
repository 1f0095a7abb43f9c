"""``data=photo``: a camera photo of the screen as the data of a reconstruction.

The photo goes through framework/photo.py (bit depth, black level, dark frame, inverse response,
flat field, saturation, rectification onto the receiver; docs/photo_import.md). What comes out
is irradiance up to the flat field's shape and an unknown scale:

- ``flat_kind: substrate`` (the flat-field photo shows the bare substrate's caustic, taken with
  the same light and screen): photo / flat is the print's irradiance relative to the bare
  substrate's, so it is multiplied by the model's caustic of flat glass;
- ``flat_kind: uniform`` (the flat shows the screen evenly lit): photo / flat is the irradiance;
- no flat: the photo is taken as the irradiance (vignetting and screen non-uniformity stay in).

``brightness: energy`` then scales it so that the weighted power equals the model's power on
the receiver with flat glass (framework/data.py); saturated pixels carry weight 0 in the data
term. The import's steps and a figure are written to the run directory (photo_import.json,
photo_import.png).
"""

from __future__ import annotations

import json

import torch

from framework.data import ReconstructionData
from framework.data_sources import DataRequest, KnownPrint, resolve_path
from framework.photo import import_photo, save_photo_figure

__all__ = ["PhotoData"]

FLAT_KINDS = ("substrate", "uniform")


class PhotoData(KnownPrint):
    """A camera photo of the caustic on the screen (``data=photo``).

    Args:
        photo: Path of the photo: 8/16-bit PNG/TIFF (grey or RGB) or a linear .npy.
        corners: The receiver's corners in the photo, [[col, row] x 4] in pixels (row 0 at the
            top), in the order bottom-left, bottom-right, top-right, top-left of the receiver.
        channel, bit_depth, response, gamma, black_level, dark, flat, saturation, supersample:
            The import's settings (framework/photo.py, import_photo).
        flat_kind: What the flat-field photo shows: ``substrate`` or ``uniform`` (module docstring).
        mask, volume, delta, brightness, mask_threshold, mask_dilation: What is known about the
            print (framework/data_sources.py, KnownPrint).
    """

    def __init__(self, photo: str | None = None, corners: list[list[float]] | None = None, channel: str = "grey",
                 bit_depth: int | None = None, response: str = "linear", gamma: float = 2.2,
                 black_level: float = 0.0, dark: str | None = None, flat: str | None = None,
                 flat_kind: str = "substrate", saturation: float = 0.98, supersample: int = 4,
                 mask: str | None = None, volume: float | str | None = None, delta: float = 0.05,
                 brightness: str = "energy", mask_threshold: float = 1e-3, mask_dilation: float = 0.05) -> None:
        if not photo:
            raise ValueError("data=photo needs data.photo=<photo .png/.tif/.npy>")
        if corners is None:
            raise ValueError("data=photo needs data.corners=[[col,row],[col,row],[col,row],[col,row]]: the "
                             "receiver's bottom-left, bottom-right, top-right and top-left corners in the photo")
        if flat_kind not in FLAT_KINDS:
            raise ValueError(f"data.flat_kind={flat_kind!r}; use {' or '.join(FLAT_KINDS)}")
        super().__init__(mask, volume, delta, brightness, mask_threshold, mask_dilation)
        self.photo, self.corners, self.flat, self.flat_kind, self.dark = str(photo), corners, flat, flat_kind, dark
        self.settings = {"channel": channel, "bit_depth": bit_depth, "response": response, "gamma": gamma,
                         "black_level": black_level, "saturation": saturation, "supersample": supersample}

    def load(self, request: DataRequest) -> ReconstructionData:
        """Import the photo onto the reconstruction's receiver; scale it; write the import's record."""
        operator = request.operator
        channels, n = operator.output_shape[0], operator.output_shape[-1]
        if channels != 1:
            raise ValueError(f"data=photo gives one channel but the scene has {channels} wavelengths; "
                             "set wavelengths=[<the filter's wavelength>], e.g. wavelengths=[0.525]")
        path = lambda p: None if p is None else resolve_path(str(p), request.base_dir)  # noqa: E731
        half_width = float(operator.scene.receiver.half_width)
        imported = import_photo(path(self.photo), self.corners, half_width, n, dark=path(self.dark),
                                flat=path(self.flat), **self.settings)
        target = torch.from_numpy(imported.image).double()
        weights = torch.from_numpy(imported.weights).double()
        steps = list(imported.steps)
        flat_render = None
        if (self.flat is not None and self.flat_kind == "substrate") or self.brightness == "energy":
            flat_render = self.bare_substrate_caustic(request)
        if self.flat is not None and self.flat_kind == "substrate":
            target = target * flat_render / float(flat_render.mean())
            steps.append("multiplied by the model's caustic of the bare substrate (flat_kind: substrate)")
        if self.brightness == "energy":
            scale = float((weights * flat_render).sum()) / float((weights * target).sum())
            target = target * scale
            steps.append(f"scaled by {scale:.4g} to the model's power on the receiver with flat glass")
        if request.output_dir is not None:
            request.output_dir.mkdir(parents=True, exist_ok=True)
            save_photo_figure(request.output_dir / "photo_import.png", imported)
            record = {"steps": steps, "corners": imported.corners.tolist(), "homography": imported.homography.tolist(),
                      "weighted_out": int((weights == 0).sum())}
            (request.output_dir / "photo_import.json").write_text(json.dumps(record, indent=2))
        for step in steps:
            print(f"photo: {step}", flush=True)
        return ReconstructionData(target=target, mask=self.printed_area(request), volume=self.deposited_volume(request),
                                  delta=self.delta, weights=weights)
