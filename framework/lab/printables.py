"""What the bench prints (the screen's marker sheet, the lens's ChArUco board): a PNG that prints at
its size and its layout beside it as JSON, read back for the import, and what both need of OpenCV's
ArUco detectors (framework/lab/screen_markers.py, framework/lab/lens.py)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

__all__ = ["aruco_dictionary", "detector_image", "load_layout", "read_layout", "save_printable"]

T = TypeVar("T")


def save_printable(image: np.ndarray, layout: dict[str, Any], path: str | Path, dpi: float) -> tuple[Path, Path]:
    """``image`` (uint8) as ``path``.png with ``dpi`` in the file, and ``layout`` as ``path``.json."""
    from PIL import Image

    png = Path(path).with_suffix(".png")
    Image.fromarray(image).save(png, dpi=(dpi, dpi))
    saved = png.with_suffix(".json")
    saved.write_text(json.dumps(layout, indent=2))
    return png, saved


def read_layout(path: str | Path, what: str) -> dict[str, Any]:
    """The JSON object at ``path``; FileNotFoundError or ValueError in one line saying it should be
    ``what`` (e.g. "a marker layout written by sfc-markers")."""
    p = Path(path)
    try:
        values = json.loads(p.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{p}: no such file; it should be {what}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ValueError(f"{p} is not {what} ({error})") from None
    if not isinstance(values, dict):
        raise ValueError(f"{p} is not {what}")
    return values


def load_layout(cls: type[T], path: str | Path, what: str) -> T:
    """``cls(**layout)`` of the layout at ``path`` (:func:`read_layout`), refused in one line when
    its keys are not ``cls``'s."""
    values = read_layout(path, what)
    try:
        return cls(**values)
    except TypeError as error:
        raise ValueError(f"{path} is not {what} ({error})") from None


def aruco_dictionary(name: str, key: str):  # noqa: ANN201 (cv2.aruco.Dictionary)
    """OpenCV's predefined ArUco dictionary ``name`` (e.g. DICT_4X4_50); ValueError in one line
    naming the setting ``key`` for a name OpenCV does not know."""
    import cv2

    dictionary_id = cv2.aruco.__dict__.get(name) if isinstance(name, str) and name.startswith("DICT_") else None
    if not isinstance(dictionary_id, int):
        raise ValueError(f"{key}={name!r} is not an OpenCV ArUco dictionary; use e.g. DICT_4X4_50 or DICT_5X5_100")
    return cv2.aruco.getPredefinedDictionary(dictionary_id)


def detector_image(values: np.ndarray) -> np.ndarray:
    """(H, W) uint8 for OpenCV's marker and board detectors from a photo's linear values (H, W[, 3]):
    grey, scaled to the 99.5th percentile and kept linear (a gamma-encoded image moves every blurred
    edge toward the dark side: 1.1-1.6 px at 1-1.5 px of blur, and loses markers at 2.5 px)."""
    grey = values.mean(axis=-1) if values.ndim == 3 else values
    top = float(np.percentile(grey, 99.5)) or 1.0
    return np.round(255 * np.clip(grey / top, 0, 1)).astype(np.uint8)
