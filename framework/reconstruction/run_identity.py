"""What determines a reconstruction's result, as a fingerprint a checkpoint carries, so that a run
resumes only from a checkpoint of the same run.

The fingerprint is one short digest per part of the config (:data:`PARTS`): the data (their config
and the bytes of every file they name), the scene, the height field, the operator, the solver, the
start and the seed. Settings that change only speed or place (the iteration cap, the operator's
device, chunk size and caches, tracking, checkpointing) are left out: a run may be resumed with a
higher cap or on another device. A mismatch is refused before anything is rendered
(:func:`check_resumable`), naming the parts that differ.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from framework.core.checkpoint import load_checkpoint

__all__ = ["PARTS", "run_fingerprint", "check_resumable"]

# Operator settings that change speed, memory or the device, not the result.
PERFORMANCE_KEYS = frozenset({"device", "chunk_size", "hit_cache_mb", "simd", "kernels", "threads"})
# data.* and height_field.* keys that name input files whose bytes are part of the fingerprint.
FILE_KEYS = ("image", "photo", "repeat", "dark", "flat", "mask", "path")
SCENE_KEYS = ("light", "substrate", "receiver", "material", "wavelengths", "units", "screen", "calibration")
PARTS = ("data", "scene", "height_field", "operator", "solver", "initial", "seed")


def _file_digest(path: Path) -> str:
    sha = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            sha.update(block)
    return sha.hexdigest()[:16]


def _with_files(section: Mapping[str, Any], base_dir: Path) -> dict[str, Any]:
    """``section`` plus the digest of each existing file it names (keys :data:`FILE_KEYS`)."""
    out = dict(section)
    for key in FILE_KEYS:
        name = section.get(key)
        if isinstance(name, str) and name not in ("design", "none"):
            path = Path(name).expanduser()
            path = path if path.is_absolute() else base_dir / path
            if path.is_file():
                out[f"{key}_sha256"] = _file_digest(path)
    return out


def _digest(value: Any) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, default=str).encode()).hexdigest()[:16]


def run_fingerprint(cfg: Mapping[str, Any], base_dir: Path) -> dict[str, str]:
    """One 16-hex-digit digest per part of :data:`PARTS` of the plain config ``cfg`` (relative file
    names resolved against ``base_dir``)."""
    operator = {k: v for k, v in dict(cfg.get("operator") or {}).items() if k not in PERFORMANCE_KEYS}
    solver = {k: v for k, v in dict(cfg.get("solver") or {}).items() if k != "max_iter"}
    parts = {
        "data": _with_files(dict(cfg.get("data") or {}), base_dir),
        "scene": {k: cfg.get(k) for k in SCENE_KEYS},
        "height_field": _with_files(dict(cfg.get("height_field") or {}), base_dir),
        "operator": {**operator, "photons": cfg.get("photons"), "photon_budget": cfg.get("photon_budget")},
        "solver": solver,
        "initial": cfg.get("initial"),
        "seed": cfg.get("seed"),
    }
    return {name: _digest(parts[name]) for name in PARTS}


def check_resumable(path: Path, fingerprint: Mapping[str, str], spec: Any) -> None:
    """Refuse, in one line, a checkpoint at ``path`` (from ``resume=spec``) that cannot be read or
    belongs to another run than the one ``fingerprint`` describes."""
    try:
        payload = load_checkpoint(path)
    except ValueError as error:
        raise ValueError(f"resume={spec}: {error}; give the checkpoint.pt of an earlier run of this config, "
                         "or resume=null to start afresh") from None
    saved = payload.get("run")
    if not isinstance(saved, dict) or not saved:
        raise ValueError(f"resume={spec}: {path} does not record which run wrote it (written by an older version); "
                         "resume=null starts afresh")
    differing = [part for part in PARTS if saved.get(part) != fingerprint.get(part)]
    if differing:
        raise ValueError(f"resume={spec}: {path} belongs to another run: its {', '.join(differing)} "
                         f"differ{'s' if len(differing) == 1 else ''} from this config; resume it with the config "
                         "in its run directory's .hydra/config.yaml, or resume=null to start afresh")
