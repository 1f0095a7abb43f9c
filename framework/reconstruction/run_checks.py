"""Checks of a reconstruction's inputs that need more than one plugin's config: they run after
every plugin is built and before the tracker opens or anything is rendered.

- :func:`check_volume`: a known deposited volume the printed area and the height bounds can hold;
- :func:`checked_resume`: the checkpoint a run continues from, readable and of the same run;
- :func:`check_tracking_target`, :func:`check_creatable_directory`: where the run's records go.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from framework.core.contracts.data_source import PrintFacts
from framework.core.plugin_config import plugin_class
from framework.files.image_io import resolve_path
from framework.reconstruction.run_identity import check_resumable
from framework.tracking.mlflow_tracker import KNOWN_SCHEMES, check_tracking_server

__all__ = [
    "check_creatable_directory",
    "check_tracking_target",
    "height_bounds",
    "check_volume",
    "check_volume_known",
    "checked_resume",
    "CHECKPOINT",
]

CHECKPOINT = "checkpoint.pt"


def height_bounds(cfg: Mapping[str, Any]) -> tuple[float, float | None]:
    """The tightest bounds (p1, p2) on the printed heights (scene units) that the solver's
    regularisers and post-steps impose (keys ``p1``/``p2``); (0, None) without an upper bound."""
    solver = cfg.get("solver") or {}
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


def check_volume_known(cfg: Mapping[str, Any], facts: PrintFacts) -> None:
    """Refuse a run whose regularisers or post-steps need the deposited volume (a plugin class
    with ``needs_volume = True``) when the data do not know it (nor will once they load)."""
    if facts.volume is not None or facts.volume_at_load:
        return
    solver = cfg.get("solver") or {}
    needing = [
        f"solver.{group}.{name}"
        for group, kind in (("regularizers", "regularizer"), ("post_steps", "post_step"))
        for name in dict(solver.get(group) or {})
        if plugin_class(kind, name).needs_volume
    ]
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


def check_creatable_directory(path: Path, key: str) -> None:
    """Refuse a directory ``path`` (config key ``key``) that cannot be created or written: it, or
    the nearest existing folder above it, is a file or not writable."""
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"{key}={path}: {existing} is a file, not a directory; give a directory (created if missing)")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"{key}={path}: {existing} cannot be written; give a directory you can write to")


def check_tracking_target(uri: str | None, store_dir: Path) -> None:
    """Refuse, before a run opens, a tracking target that cannot take it: an unknown URI scheme, a
    server that is not MLflow, or (``uri`` None) a local ``store_dir`` that is a file or lies
    under one or in a directory that cannot be written."""
    if uri is not None:
        if not isinstance(uri, str) or not uri:
            raise ValueError(f"tracking.uri={uri!r} must be an MLflow tracking URI (e.g. http://host:5000, "
                             "sqlite:///path/mlflow.db) or null for the local store tracking.store_dir")
        scheme = uri.split("://", 1)[0].lower() if "://" in uri else ""
        if scheme and scheme not in KNOWN_SCHEMES:
            raise ValueError(f"tracking.uri={uri}: unknown scheme {scheme!r}; use one of {', '.join(KNOWN_SCHEMES)} "
                             "or tracking.uri=null for the local store tracking.store_dir")
        check_tracking_server(uri)
        return
    check_creatable_directory(store_dir, "tracking.store_dir")
