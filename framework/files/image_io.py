"""Reading caustic images and printed-area masks from files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from PIL import Image, UnidentifiedImageError

from framework.files.height_field_io import load_npy


def resolve_path(path: str | Path, base_dir: Path) -> Path:
    """``path`` with ~ expanded, relative to ``base_dir`` unless absolute."""
    p = Path(path).expanduser()
    return p if p.is_absolute() else base_dir / p


def existing_file(path: str | Path, what: str) -> Path:
    """``path`` as a Path once it is known to be a file; ``what`` names it in the one-line error."""
    p = Path(path).expanduser()
    if p.is_dir():
        raise ValueError(f"{what} {str(p)!r} is a directory; give the file itself")
    if not p.is_file():
        raise FileNotFoundError(f"{what} file {str(p)!r} does not exist; check the path (relative paths are "
                                "resolved against the directory the command was started in)")
    return p


def _read_array(p: Path) -> np.ndarray:
    if p.suffix.lower() == ".npy":
        return load_npy(p, "write it again with numpy.save")
    if p.suffix.lower() in (".png", ".tif", ".tiff"):
        try:
            with Image.open(p) as img:
                array = np.array(img)
        except (UnidentifiedImageError, OSError) as error:
            raise ValueError(f"{p} cannot be read as an image, corrupt or truncated ({str(error)[:80]}); save it "
                             "again as an 8/16-bit PNG/TIFF") from None
        if array.dtype == np.uint8 or array.dtype == np.uint16:
            array = array.astype(np.float64) / np.iinfo(array.dtype).max
        return array
    raise ValueError(f"unsupported file type {p.suffix!r} for {p.name}; use .npy, .png or .tif")


def load_caustic_image(path: str | Path) -> torch.Tensor:
    """Caustic image as float64 (c, n, n), rows = +y upward as written by sfc-simulate.

    .npy: (n, n) or (c, n, n) as written by ``sfc-simulate`` (W per scene unit^2). PNG/TIFF
    (8 or 16 bit, grey or RGB): values scaled to [0, 1]; the first image row is the top (+y), as
    in a photo, so rows are flipped to the [row = y increasing] convention.
    """
    p = existing_file(path, "caustic image")
    array = _read_array(p).astype(np.float64)
    if p.suffix.lower() != ".npy":
        array = array[::-1] if array.ndim == 2 else array[::-1, :, :3].transpose(2, 0, 1)
        array = np.ascontiguousarray(array)
    if array.ndim == 2:
        array = array[None]
    if array.ndim != 3 or array.shape[1] != array.shape[2]:
        raise ValueError(f"caustic image {p.name} has shape {array.shape}; expected square (n, n) or (c, n, n)")
    if not np.isfinite(array).all():
        raise ValueError(f"caustic image {p.name} contains NaN or infinite values; clean it first")
    return torch.from_numpy(array)


def load_mask(path: str | Path, resolution: int) -> torch.Tensor:
    """Printed-area mask (m, m) bool: non-zero pixels may hold material. Same row convention as images."""
    p = existing_file(path, "mask")
    array = _read_array(p)
    if array.ndim == 3:
        array = array[..., 0]
    if p.suffix.lower() != ".npy":
        array = array[::-1]
    if array.shape != (resolution, resolution):
        raise ValueError(f"mask {p.name} has shape {array.shape}; it must match the height field "
                         f"({resolution}, {resolution}): resize it or set height_field.resolution")
    if not np.isfinite(array.astype(np.float64)).all():
        raise ValueError(f"mask {p.name} contains NaN values")
    return torch.from_numpy(np.ascontiguousarray(array) > 0)
