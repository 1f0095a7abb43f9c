"""Checks of a reconstruction's inputs that need more than one plugin's config: they run after
every plugin is built and before the tracker opens or anything is rendered.

- :func:`check_volume`: a known deposited volume the printed area and the height bounds can hold;
- :func:`checked_resume`: the checkpoint a run continues from, readable and of the same run;
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

from framework.core.contracts.data_source import PrintFacts
from framework.core.plugin_config import plugin_class
from framework.files.image_io import resolve_path
from framework.reconstruction.run_identity import check_resumable
from regularizers import PostStepUpdate, Regularizer

__all__ = [
    "height_bounds",
    "volume_needed_by",
    "check_volume",
    "check_volume_known",
    "checked_resume",
    "CHECKPOINT",
]

CHECKPOINT = "checkpoint.pt"


def height_bounds(solver: Mapping[str, Any]) -> tuple[float, float | None]:
    """The tightest bounds (p1, p2) on the printed heights (scene units) that the ``solver`` group's
    regularisers and post-steps impose (keys ``p1``/``p2``); (0, None) without an upper bound."""
    lower, upper = 0.0, None
    for group in ("regularizers", "post_steps"):
        for params in dict(solver.get(group) or {}).values():
            params = params or {}
            if isinstance(params.get("p1"), (int, float)):
                lower = max(lower, float(params["p1"]))
            if isinstance(params.get("p2"), (int, float)):
                upper = float(params["p2"]) if upper is None else min(upper, float(params["p2"]))
    return lower, upper


def check_volume(volume: float | None, mask: torch.Tensor, cell_area: float, bounds: tuple[float, float | None],
                 plate_width: float) -> None:
    """Refuse a deposited volume (scene units^3) the printed area ``mask`` (m, m) cannot hold:
    more than the upper bound everywhere on it, less than the lower bound, or a mean height over
    the printed area above the plate's width."""
    if volume is None:
        return
    area = float(mask.sum()) * cell_area
    if not area > 0:
        raise ValueError(f"data.volume={volume:.4g} is given but the printed area (data.mask) is empty; give a mask "
                         "that covers the print, or data.mask=null")
    mean = volume / area
    lower, upper = bounds
    if upper is not None and mean > upper:
        raise ValueError(
            f"data.volume={volume:.4g} scene units^3 needs a mean height of {mean:.4g} over the printed "
            f"area ({area:.4g} units^2), above the height bound p2={upper:g}: check the value and its unit "
            "(scene units^3, or a string such as '1.7 mm3'), the mask, or raise the bound"
        )
    if mean < lower:
        raise ValueError(f"data.volume={volume:.4g} scene units^3 gives a mean height of {mean:.4g} over the printed "
                         f"area, below the height bound p1={lower:g}: check the value, its unit and the mask")
    if mean > plate_width:
        raise ValueError(f"data.volume={volume:.4g} scene units^3 gives a mean height of {mean:.4g} over the printed "
                         f"area, taller than the plate is wide ({plate_width:g}): check the value and its unit "
                         "(scene units^3, or a string such as '1.7 mm3')")


def volume_needed_by(solver: Mapping[str, Any]) -> list[str]:
    """The config keys of the ``solver`` group's regularisers and post-steps that need the
    deposited volume (a plugin class with ``needs_volume = True``)."""
    return [
        f"solver.{group}.{name}"
        for group, kind, base in (("regularizers", "regularizer", Regularizer),
                                  ("post_steps", "post_step", PostStepUpdate))
        for name in dict(solver.get(group) or {})
        if plugin_class(kind, name, base).needs_volume
    ]


def check_volume_known(needing: Sequence[str], facts: PrintFacts) -> None:
    """Refuse a run whose plugins ``needing`` the deposited volume (:func:`volume_needed_by`)
    when the data do not know it (nor will once they load)."""
    if facts.volume is not None or facts.volume_at_load:
        return
    if needing:
        raise ValueError(f"{' and '.join(needing)} need{'s' if len(needing) == 1 else ''} the deposited volume: set "
                         "data.volume=... (scene units^3 or e.g. '1.7 mm3'), or leave "
                         f"{'it' if len(needing) == 1 else 'them'} out ({' '.join(repr('~' + n) for n in needing)})")


def checked_resume(spec: Any, output_dir: Path, base_dir: Path, fingerprint: Mapping[str, str]) -> Path | None:
    """The checkpoint a run continues from, checked: ``auto`` takes the run directory's own
    checkpoint.pt when there is one (a sweep job run again in its directory, e.g. requeued after
    pre-emption), a path takes that file, None starts afresh. The file must be readable and
    written by a run with this ``fingerprint`` (framework/reconstruction/run_identity.py)."""
    if spec in (None, "none", "null"):
        return None
    if spec == "auto":
        own = output_dir / CHECKPOINT
        path = own if own.is_file() else None
    else:
        path = resolve_path(str(spec), base_dir)
        if not path.is_file():
            raise FileNotFoundError(f"resume={spec!r}: {path} is not a file; give a checkpoint.pt of an earlier run, "
                                    "auto or null")
    if path is not None:
        check_resumable(path, fingerprint, spec)
    return path
