"""What the bench prints (the screen's marker sheet, the lens's ChArUco board): a PNG that prints at
its size and its layout beside it as JSON, read back for the import (framework/lab/screen_markers.py,
framework/lab/lens.py)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["read_layout", "save_printable"]


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
