"""Where the data of a reconstruction come from: plugins of kind ``data`` (config group ``data``).

- ``synthetic`` (:class:`SyntheticData`): the configured height field is the ground truth; two
  independent reference renders give the clean caustic and its intrinsic noise, then noise is
  added up to the level delta (framework/core/data.py).
- ``file`` (:class:`FileData`): a caustic image from a file, with the printed-area mask and
  the deposited volume when known.
- ``photo`` (framework/lab/photo_data.py): a camera photo of the screen, rectified onto the receiver.

Each keeps the data contract (framework/core/contracts/data_source.py): built from its config
alone, ``check(request)`` before a run opens, ``load(request)`` once it runs.
"""

from __future__ import annotations

import torch

from framework.core.contracts.data_source import DataRequest, DataSource, PrintFacts
from framework.core.data import ReconstructionData, measured_data, synthetic_data, validate_delta
from framework.core.masks import mask_from_height_field
from framework.core.units import scene_volume
from framework.files.height_field_io import load_height_field
from framework.files.image_io import load_caustic_image, load_mask, resolve_path
from operators.values import checked_number, checked_whole, is_number

__all__ = ["KnownPrint", "file_setting", "SyntheticData", "FileData"]


def dilation_setting(value: float) -> float:
    """``data.mask_dilation``: a fraction of the grid's width in [0, 1]."""
    value = checked_number(value, "data.mask_dilation", 0.0, must="must be a finite number >= 0")
    if value > 1.0:
        raise ValueError(f"data.mask_dilation={value!r} must be a fraction of the grid's width in [0, 1], e.g. 0.05")
    return value


def file_setting(name: str, value: object) -> str | None:
    """A file name given as ``data.<name>``: a non-empty string or None."""
    if value is not None and (not isinstance(value, str) or not value):
        raise ValueError(f"data.{name}={value!r} must be a file name (a string) or null")
    return value


class SyntheticData(DataSource):
    """Noisy caustic of the configured height field (framework/core/data.py, :func:`synthetic_data`).

    Args:
        delta: Relative noise level ||b^delta - b|| / ||b|| in (0, 1).
        reference: ``exact``: the truth rendered by the operator's exact method, free of the
            model's footprint, photons and seed (``exact_variant``: wavefront triangles for the
            height field); ``model``: by the model itself at the references' sampling (the paper's
            protocol: data and model share the model's blur).
        reference_photons: Photons of each of the two independent reference renders (wavefront
            triangles: about this many vertices, rendered once: they carry no noise).
        reference_resolution: Receiver pixels of the references (resampled to the reconstruction's).
        mask_threshold: Printed area N^: |d_true| >= threshold ...
        mask_dilation: ... dilated by this fraction of the grid width.
        printed: A height-field file (.npy in scene units or a 16-bit PNG; the reconstruction's grid)
            of what was printed: the data are its caustic and the configured height field is the
            print's design (its printed area gives the mask, as for a measured print). None: the
            configured height field was printed exactly and is the ground truth, with no design.
    """

    length_keys = ("mask_threshold",)  # may be given with a unit, e.g. '0.02 mm' (framework/core/plugin_config.py)

    @staticmethod
    def example_settings() -> dict[str, int]:
        """Settings of the contract checks (framework/core/contracts/checks.py): small reference renders."""
        return {"reference_photons": 1 << 18, "reference_resolution": 64}

    REFERENCES = ("exact", "model")

    def __init__(self, delta: float = 0.05, reference: str = "exact", reference_photons: int = 1 << 22,
                 reference_resolution: int = 256, mask_threshold: float = 1e-3, mask_dilation: float = 0.05,
                 printed: str | None = None) -> None:
        if reference not in self.REFERENCES:
            raise ValueError(f"data.reference={reference!r}; use exact (an independent exact render of the truth) "
                             "or model (the model's own render, the paper's protocol)")
        self.reference = reference
        self.delta = validate_delta(delta)
        self.reference_photons = checked_whole(reference_photons, "data.reference_photons", 1)
        self.reference_resolution = checked_whole(reference_resolution, "data.reference_resolution", 2)
        self.mask_threshold = checked_number(mask_threshold, "data.mask_threshold", 0.0,
                                             must="must be a finite number >= 0")
        self.mask_dilation = dilation_setting(mask_dilation)
        self.printed = file_setting("printed", printed)

    def printed_heights(self, request: DataRequest) -> torch.Tensor:
        """The printed heights (m, m), float64: ``printed`` on the reconstruction's grid, else the
        configured height field."""
        if self.printed is None:
            return request.configured_heights()
        file = resolve_path(self.printed, request.base_dir)
        if not file.is_file():
            raise FileNotFoundError(f"data.printed={self.printed!r}: {file} does not exist; give the printed "
                                    "heights as .npy (scene units) or a 16-bit PNG")
        heights = torch.from_numpy(load_height_field(file))
        m = request.grid.resolution
        if tuple(heights.shape) != (m, m):
            raise ValueError(f"data.printed={self.printed!r} has {heights.shape[0]} x {heights.shape[1]} samples, "
                             f"the design {m} x {m}; give the print on the design's grid (height_field.resolution)")
        return heights

    def check(self, request: DataRequest) -> PrintFacts:
        """The printed area of the design (with ``printed``) or of the ground truth (its volume,
        known exactly once loaded, is not checked)."""
        self.printed_heights(request)
        heights = request.configured_heights()
        return PrintFacts(mask_from_height_field(heights, self.mask_threshold, self.mask_dilation), None,
                          volume_at_load=True)

    def load(self, request: DataRequest) -> ReconstructionData:
        """Render the printed heights (twice, seeds seed + 1000 and seed + 2000, unless the method is
        deterministic) and add the noise."""
        operator = request.operator
        truth = self.printed_heights(request).to(operator.dtype)
        design = None if self.printed is None else request.configured_heights().double()
        make = operator.exact_variant if self.reference == "exact" else operator.variant
        first = make(self.reference_photons, request.seed + 1000, self.reference_resolution)
        second = None if first.deterministic else make(
            self.reference_photons, request.seed + 2000, self.reference_resolution)
        return synthetic_data(truth, first.render, second.render if second is not None else None,
                              operator.output_shape[-1], self.delta, request.seed, request.grid.cell_area,
                              self.mask_threshold, self.mask_dilation, design)


class KnownPrint(DataSource):
    """What a measured data source knows about the print besides its image (the shared settings of
    ``data=file`` and ``data=photo``).

    Args:
        mask: Printed-area mask file, ``design`` (the configured height field, thresholded and
            dilated) or None (everywhere).
        volume: Deposited volume, scene units^3 or a string such as '1.7 mm3', or None when unknown.
        delta: Estimated relative noise level of the image.
        brightness: ``energy``: scale the image to the power the model puts on the receiver with the
            bare substrate; ``as_is``: use the values.
        mask_threshold, mask_dilation: The rule of ``mask: design``.
    """

    length_keys = ("mask_threshold",)  # may be given with a unit, e.g. '0.02 mm' (framework/core/plugin_config.py)

    BRIGHTNESS = ("energy", "as_is")

    def __init__(self, mask: str | None, volume: float | str | None, delta: float, brightness: str,
                 mask_threshold: float, mask_dilation: float) -> None:
        if brightness not in self.BRIGHTNESS:
            raise ValueError(f"data.brightness={brightness!r}; use {' or '.join(self.BRIGHTNESS)}")
        if volume is not None and not isinstance(volume, str) and not is_number(volume):
            raise ValueError(f"data.volume={volume!r} must be a number (scene units^3), a string such as '1.7 mm3', "
                             "or null")
        self.mask, self.volume, self.brightness = file_setting("mask", mask), volume, brightness
        self.delta = validate_delta(delta)
        self.mask_threshold = checked_number(mask_threshold, "data.mask_threshold", 0.0,
                                             must="must be a finite number >= 0")
        self.mask_dilation = dilation_setting(mask_dilation)

    def printed_area(self, request: DataRequest) -> torch.Tensor:
        """The printed-area mask (m, m) bool: everywhere (no mask), the design's printed area
        dilated, or the mask file."""
        m = request.grid.resolution
        if self.mask in (None, "none"):
            return torch.ones(m, m, dtype=torch.bool)
        if self.mask == "design":
            return mask_from_height_field(request.configured_heights(), self.mask_threshold, self.mask_dilation)
        return load_mask(resolve_path(self.mask, request.base_dir), m)

    def deposited_volume(self, request: DataRequest) -> float | None:
        """The deposited volume in scene units^3 (framework/core/units.py), or None when unknown."""
        if self.volume is None:
            return None
        volume = scene_volume(self.volume, request.mm_per_unit, "data.volume")
        if not volume > 0.0:
            raise ValueError(f"data.volume={self.volume} must be positive (scene units^3 or e.g. '1.7 mm3') or null")
        return volume

    def check(self, request: DataRequest) -> PrintFacts:
        """The mask and the volume read and checked."""
        return PrintFacts(self.printed_area(request), self.deposited_volume(request))

    @staticmethod
    def bare_substrate_caustic(request: DataRequest) -> torch.Tensor:
        """The model's caustic (c, n, n) of the substrate without a print, float64."""
        m = request.grid.resolution
        operator = request.operator
        return operator.render(torch.zeros(m, m, dtype=operator.dtype)).double()


class FileData(KnownPrint):
    """A caustic image from a file (``data=file``).

    Args:
        image: Caustic .npy (as written by sfc-simulate) or 8/16-bit .png/.tif.
        mask, volume, delta, brightness, mask_threshold, mask_dilation: What is known about the
            print (:class:`KnownPrint`).
    """

    def __init__(self, image: str | None = None, mask: str | None = None, volume: float | str | None = None,
                 delta: float = 0.05, brightness: str = "energy", mask_threshold: float = 1e-3,
                 mask_dilation: float = 0.05) -> None:
        if not image:
            raise ValueError("data=file needs data.image=<caustic .npy/.png/.tif>")
        super().__init__(mask, volume, delta, brightness, mask_threshold, mask_dilation)
        self.image = file_setting("image", image)

    def _image(self, request: DataRequest) -> torch.Tensor:
        """The caustic image (c, N, N), its channels checked against the scene's wavelengths."""
        image = load_caustic_image(resolve_path(self.image, request.base_dir))
        channels = request.operator.output_shape[0]
        if image.shape[0] != channels:
            raise ValueError(f"data.image has {image.shape[0]} channel(s) but the scene has {channels} "
                             "wavelength(s); set wavelengths=[...] to match")
        if float(image.sum()) <= 0.0:
            raise ValueError(f"data.image={self.image} is all zero (or negative); check the file")
        return image

    def check(self, request: DataRequest) -> PrintFacts:
        """The image, the mask and the volume read and checked."""
        self._image(request)
        return super().check(request)

    def load(self, request: DataRequest) -> ReconstructionData:
        """Read the image and the mask; scale the image (``brightness: energy``)."""
        operator = request.operator
        image = self._image(request)
        flat_total = float(self.bare_substrate_caustic(request).sum()) if self.brightness == "energy" else None
        return measured_data(image, operator.output_shape[-1], self.delta, self.printed_area(request),
                             self.deposited_volume(request), flat_total,
                             source=str(resolve_path(self.image, request.base_dir).resolve()))
