"""Read and write printed height fields d (m, m) in scene units.

Formats:
- ``.npy``: a 2-D square float array, values in scene units (times ``scale``), rows = y as in
  the array convention [row, col] = [y, x].
- ``.png`` / ``.tif`` / ``.tiff``: an 8- or 16-bit greyscale image; height = value /
  max_of_dtype * ``scale`` scene units. Images are stored as seen from above with +y up, so the
  file's top row is y = +1 (the rows are flipped relative to the array).

Example:
    >>> import tempfile, pathlib
    >>> d = np.zeros((8, 8)); d[2, 3] = 0.05
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "d.npy"
    >>> save_height_field(path, d)
    1.0
    >>> float(load_height_field(path)[2, 3])
    0.05
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

from operators.values import checked_number, checked_whole

__all__ = [
    "load_height_field",
    "save_height_field",
    "resample",
    "load_npy",
    "read_npy",
    "validate_heights",
    "IMAGE_SUFFIXES",
]

IMAGE_SUFFIXES = (".png", ".tif", ".tiff")
NPY_FIX = "save the heights again with numpy.save"
# Full-scale value of each accepted Pillow greyscale mode.
_MODE_MAX = {"L": 255.0, "I;16": 65535.0, "I;16B": 65535.0, "I;16L": 65535.0, "I;16N": 65535.0}


def _read_image(path: Path) -> np.ndarray:
    """Greyscale image as float64 in [0, 1] (value / max_of_dtype), rows flipped so row 0 is y = -1."""
    with Image.open(path) as img:
        mode = img.mode
        values = np.asarray(img, dtype=np.float64)
    if mode in _MODE_MAX:
        full = _MODE_MAX[mode]
    elif mode == "I" and values.size and values.min() >= 0.0 and values.max() <= 65535.0:
        full = 65535.0  # Pillow reads 16-bit greyscale PNGs as mode "I"
    else:
        raise ValueError(f"{path}: image mode {mode!r} is not 8/16-bit greyscale; save it as an 8- or "
                         "16-bit grey PNG/TIFF")
    return values[::-1] / full


def resample(heights: np.ndarray, resolution: int) -> np.ndarray:
    """Resample (k, k) heights to (m, m), m = ``resolution``; samples stay at linspace(-1, 1, .).

    Upsampling is bicubic with aligned corners; downsampling averages areas. Bicubic overshoot
    below zero is clipped to 0.
    """
    m = checked_whole(resolution, "resolution", 2, example="128")
    if heights.shape == (m, m):
        return heights.copy()
    t = torch.from_numpy(np.ascontiguousarray(heights, dtype=np.float64))[None, None]
    if m > heights.shape[0]:
        out = F.interpolate(t, size=(m, m), mode="bicubic", align_corners=True)
    else:
        out = F.interpolate(t, size=(m, m), mode="area")
    return np.clip(out[0, 0].numpy(), 0.0, None)


def load_npy(path: str | Path, fix: str = NPY_FIX) -> np.ndarray:
    """The array in the .npy file ``path`` as stored (no pickles); a file that does not hold one
    complete .npy array (corrupt, truncated, or holding objects) or that cannot be read is refused in
    one line naming it and ``fix``."""
    try:
        array = np.load(path, allow_pickle=False)
    except OSError as error:
        raise ValueError(f"{path} cannot be read ({error.strerror or error}); {fix}") from None
    except (ValueError, EOFError, zipfile.BadZipFile):  # numpy's words for a bad header, short data or objects
        raise ValueError(f"{path} is corrupt or truncated (not a complete .npy array of numbers); {fix}") from None
    if not isinstance(array, np.ndarray):
        raise ValueError(f"{path} holds several arrays, not an array of numbers; {fix}")
    return array


def read_npy(path: str | Path, fix: str = NPY_FIX) -> np.ndarray:
    """The array of numbers in the .npy file ``path`` as float64 (:func:`load_npy`); text or other
    values that are not numbers are refused in one line naming the file and ``fix``."""
    array = load_npy(path, fix)
    if array.dtype.kind not in "biuf":
        raise ValueError(f"{path} holds {array.dtype} values, not an array of numbers; {fix}")
    return np.asarray(array, dtype=np.float64)


def validate_heights(path: str | Path, heights: np.ndarray, fix: str | None = None, nonnegative: bool = True) -> None:
    """Refuse heights read from ``path`` that are not a square 2-D array (m, m) with m >= 2 of finite
    values (and, with ``nonnegative``, >= 0), in one line naming the file (and ``fix``, else how to
    repair the array)."""
    if heights.ndim != 2 or heights.shape[0] != heights.shape[1] or heights.shape[0] < 2:
        raise ValueError(f"{path}: height field must be a square 2-D array, got shape {heights.shape}; "
                         f"{fix or 'crop or pad it to (m, m), m >= 2'}")
    bad = np.argwhere(~np.isfinite(heights))
    if bad.size:
        i, j = bad[0]
        raise ValueError(f"{path}: height field contains {len(bad)} NaN or infinite values (the first at "
                         f"[{i}, {j}]: {heights[i, j]}); {fix or 'replace them (e.g. by 0)'}")
    if nonnegative and heights.min() < 0.0:
        raise ValueError(f"{path}: height field has negative values (min {heights.min():.4g}); heights "
                         "are printed glass and must be >= 0")


def load_height_field(path: str | Path, resolution: int | None = None, scale: float = 1.0) -> np.ndarray:
    """Load a height field as float64 (m, m) in scene units.

    Args:
        path: ``.npy`` (2-D square array) or 8/16-bit greyscale ``.png``/``.tif``/``.tiff``.
        resolution: resample to m x m when given and different from the file's size.
        scale: multiplies the heights; for images it is the height (scene units) of full white.

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: unsupported suffix or image mode, a corrupt or truncated .npy, not square 2-D,
            NaN/inf, negative values, or a scale that is not a finite number >= 0.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"height field file {str(path)!r} does not exist; check height_field.path")
    checked_number(scale, "scale", least=0.0, unit="scene units", example="1.0")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        heights = read_npy(path)
    elif suffix in IMAGE_SUFFIXES:
        heights = _read_image(path)
    else:
        raise ValueError(f"{path}: unsupported suffix {suffix!r}; use .npy, .png, .tif or .tiff")
    validate_heights(path, heights)
    heights = heights * float(scale)
    if resolution is not None:
        heights = resample(heights, resolution)
    return np.ascontiguousarray(heights)


def save_height_field(path: str | Path, heights: np.ndarray | torch.Tensor, scale: float | None = None) -> float:
    """Write heights (m, m) in scene units; returns the ``scale`` that ``load_height_field`` needs.

    ``.npy`` stores float64 values / scale (scale defaults to 1.0). Images store 16-bit grey
    round(d / scale * 65535), +y up; scale defaults to max(d) (1.0 for an all-zero field) and
    heights above it are refused.
    """
    path = Path(path)
    d = heights.detach().cpu().numpy() if isinstance(heights, torch.Tensor) else np.asarray(heights)
    d = d.astype(np.float64)
    validate_heights(path, d)
    suffix = path.suffix.lower()
    if scale is None:
        scale = 1.0 if suffix == ".npy" or float(d.max(initial=0.0)) == 0.0 else float(d.max())
    checked_number(scale, "scale", above=0.0, unit="scene units")
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".npy":
        np.save(path, d / scale)
    elif suffix in IMAGE_SUFFIXES:
        if d.max(initial=0.0) > scale * (1.0 + 1e-12):
            raise ValueError(f"max height {d.max():.4g} exceeds scale={scale}; pass scale >= the max height")
        grey = np.round(np.clip(d / scale, 0.0, 1.0) * 65535.0).astype(np.uint16)
        Image.fromarray(np.ascontiguousarray(grey[::-1])).save(path)
    else:
        raise ValueError(f"{path}: unsupported suffix {suffix!r}; use .npy, .png, .tif or .tiff")
    return float(scale)
