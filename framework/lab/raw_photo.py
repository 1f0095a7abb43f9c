"""Camera RAW photos read linearly through LibRaw (rawpy): the sensor's own counts, nothing the
camera's or a converter's pipeline adds (no white balance, colour matrix, tone curve or
brightening).

Every photosite has the file's black level of its position subtracted and is divided by white
level - black level, so a value is a fraction of the sensor's full scale in [0, 1]. Each colour
(red, green, blue) is then filled in at every photo pixel by bilinear interpolation of its own
photosites (normalised convolution with the kernel [1 2 1]^T [1 2 1] / 4; a photosite keeps its
own value), a linear map, so the frame keeps the photo's size, pixel coordinates and resolution.
A pixel whose interpolation reaches a photosite at the white level reads 1 in that colour, so the
import's saturation test (framework/lab/photo_import.py, ``data.saturation``) sees it. The frame is
turned as the file says the camera was held (LibRaw's ``flip``), as a viewer shows it.

Mosaics other than a 2 x 2 pattern of red, green and blue (Fuji's X-Trans, CMYG, linear DNGs)
are refused in one line with a way to convert them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["RAW_SUFFIXES", "RawFrame", "read_raw"]

# What LibRaw reads and users of this field bring: Adobe DNG and the common camera formats.
RAW_SUFFIXES = (".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".raf", ".orf", ".rw2",
                ".pef", ".srw", ".3fr", ".iiq", ".erf", ".kdc", ".mef", ".mos", ".x3f")
_CONVERT = ("convert it to a 16-bit linear TIFF of the sensor's values (e.g. dcraw -4 -D -T) and give that with "
            "data.black_level")
# LibRaw's flip: 0 none, 3 turned 180 degrees, 5 a quarter turn counter-clockwise, 6 clockwise.
_QUARTER_TURNS = {0: 0, 3: 2, 5: 1, 6: -1}
_BILINEAR = np.outer([1.0, 2.0, 1.0], [1.0, 2.0, 1.0]) / 4.0  # bilinear interpolation on a Bayer colour's sites


@dataclass(frozen=True)
class RawFrame:
    """A RAW photo as linear colour values.

    Attributes:
        values: (H, W, 3) float64, red, green, blue as fractions of full scale in [0, 1], row 0 =
            top as the file says the camera was held; H, W even.
        black: The black level of each colour (R, G, B), sensor counts.
        white: The white level (saturation), sensor counts.
        pattern: The mosaic's 2 x 2 colours in reading order, e.g. 'RGGB'.
    """

    values: np.ndarray
    black: tuple[float, float, float]
    white: float
    pattern: str

    def describe(self) -> str:
        """One line for the import's steps."""
        height, width = self.values.shape[:2]
        black = ", ".join(f"{b:g}" for b in self.black)
        return (f"{width} x {height} px camera RAW, {self.pattern} mosaic read linearly (black {black}, white "
                f"{self.white:g} counts; each colour interpolated bilinearly from its photosites)")


def read_raw(path: str | Path, what: str = "photo") -> RawFrame:
    """The RAW file ``path`` as a :class:`RawFrame`; ``what`` names it in messages. ValueError in
    one line for a file LibRaw cannot read or a mosaic it cannot split into red, green and blue."""
    import rawpy  # the lab's optional reader: imported only for RAW files

    p = Path(path)
    try:
        raw = rawpy.imread(str(p))
    except (rawpy.LibRawError, OSError) as error:
        raise ValueError(f"{what} {p.name} cannot be read as a camera RAW file by LibRaw {rawpy.libraw_version} "
                         f"({type(error).__name__}: {error}); an unknown or newer camera may need a newer rawpy "
                         f"(pip install -U rawpy), or {_CONVERT}") from None
    with raw:
        pattern = np.asarray(raw.raw_pattern) if raw.raw_pattern is not None else np.zeros((0, 0))
        desc = raw.color_desc.decode("ascii", "replace")
        if pattern.shape != (2, 2):
            raise ValueError(f"{what} {p.name} has a {'x'.join(map(str, pattern.shape)) or 'non-mosaic'} colour "
                             f"pattern ({desc}), not a 2 x 2 Bayer mosaic; {_CONVERT}")
        colours = "".join(desc[int(c)] for c in pattern.ravel())
        if sorted(colours) != ["B", "G", "G", "R"]:
            raise ValueError(f"{what} {p.name} has a {colours} mosaic; only red-green-blue Bayer mosaics are read, "
                             f"{_CONVERT}")
        counts = np.asarray(raw.raw_image_visible, dtype=np.float64)
        blacks = np.asarray(raw.black_level_per_channel, dtype=np.float64)
        white = float(raw.white_level)
        flip = int(raw.sizes.flip)
    rows, cols = counts.shape[0] // 2 * 2, counts.shape[1] // 2 * 2
    if rows < 2 or cols < 2:
        raise ValueError(f"{what} {p.name} has a {counts.shape[1]} x {counts.shape[0]} sensor image; too small to read")
    counts = counts[:rows, :cols]
    sites = {c: np.zeros((rows, cols), dtype=bool) for c in "RGB"}
    black_map = np.empty((rows, cols))
    black_of: dict[str, float] = {}
    for k, colour in enumerate(colours):
        i, j = divmod(k, 2)
        black_of[colour] = black_map[i::2, j::2] = float(blacks[int(pattern[i, j])])
        sites[colour][i::2, j::2] = True
    fraction = np.clip((counts - black_map) / (white - black_map), 0.0, 1.0)
    values = np.stack([_interpolated(fraction, sites[c]) for c in "RGB"], axis=-1)
    values = np.rot90(values, _QUARTER_TURNS.get(flip, 0)).copy()
    return RawFrame(values, (black_of["R"], black_of["G"], black_of["B"]), white, colours)


def _interpolated(fraction: np.ndarray, sites: np.ndarray) -> np.ndarray:
    """One colour (H, W) at every pixel from its photosites ``sites`` (bool (H, W)): its own value
    there, elsewhere the bilinear interpolation of the neighbouring ones; 1 where that reaches a
    photosite at the white level."""
    from scipy.ndimage import convolve

    weight = convolve(sites.astype(np.float64), _BILINEAR, mode="mirror")
    value = convolve(np.where(sites, fraction, 0.0), _BILINEAR, mode="mirror") / weight
    clipped = convolve((sites & (fraction >= 1.0)).astype(np.float64), _BILINEAR, mode="mirror") > 0.0
    return np.where(sites, fraction, np.where(clipped, 1.0, value))

