"""The run's input data as an MLflow dataset: named after what they are (the synthetic scene, or the
file a data source read), with a source and a digest, so that runs on the same data group in the
MLflow UI (docs/dashboard.md). Logged by framework/tracking/mlflow_tracker.py (``MlflowTracker.log_data``).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from mlflow.data.numpy_dataset import NumpyDataset

    from framework.core.data import ReconstructionData

__all__ = ["dataset_digest", "data_dataset"]

UNNAMED = "unknown"


def dataset_digest(arrays: Mapping[str, np.ndarray], values: Mapping[str, Any]) -> str:
    """A 16-hex-digit SHA-256 of ``values`` (as sorted JSON) and each array's dtype, shape and bytes."""
    sha = hashlib.sha256(json.dumps(values, sort_keys=True, default=str).encode())
    for name in sorted(arrays):
        array = np.ascontiguousarray(arrays[name])
        sha.update(f"{name}:{array.dtype.str}:{array.shape}".encode())
        sha.update(array.tobytes())
    return sha.hexdigest()[:16]


def _data_arrays(data: ReconstructionData) -> dict[str, np.ndarray]:
    """The caustic target (c, n, n), the mask (m, m) and, if known, the volume (1,) as numpy arrays."""
    arrays = {"caustic": data.target.detach().cpu().numpy(), "mask": data.mask.detach().cpu().numpy()}
    if data.volume is not None:
        arrays["volume"] = np.array([data.volume], dtype=np.float64)
    return arrays


def _synthetic_description(cfg: Mapping[str, Any]) -> dict[str, Any]:
    """What synthetic data are made from: the data settings (noise level delta, reference renders),
    the height field (shape or path) and the seed."""
    return {"data": dict(cfg.get("data") or {}), "height_field": dict(cfg.get("height_field") or {}),
            "seed": cfg.get("seed", 0)}


def data_dataset(data: ReconstructionData, cfg: Mapping[str, Any]) -> NumpyDataset:
    """The run's input data as an MLflow numpy dataset (features caustic, mask and volume).

    Synthetic data (with a ground truth): named ``synthetic:<shape or file>``, a code source
    describing the scene, seed and noise level, the digest of that description and the target.
    Measured data: named after the file they were read from (``data.source``), a local source
    with its path, the digest of the arrays.
    """
    import mlflow.data
    from mlflow.data.code_dataset_source import CodeDatasetSource
    from mlflow.data.dataset_source_registry import get_dataset_source_from_json

    arrays = _data_arrays(data)
    if data.ground_truth is not None:
        description = _synthetic_description(cfg)
        field = description["height_field"]
        scene = Path(str(field["path"])).name if field.get("path") else field.get("shape", UNNAMED)
        return mlflow.data.from_numpy(arrays, source=CodeDatasetSource(tags=description), name=f"synthetic:{scene}",
                                      digest=dataset_digest({"caustic": arrays["caustic"]}, description))
    path = Path(data.source) if data.source else None
    uri = str(path) if path is not None else UNNAMED
    source = get_dataset_source_from_json(json.dumps({"uri": uri}), source_type="local")
    name = path.name if path is not None else str((cfg.get("data") or {}).get("name", UNNAMED))
    return mlflow.data.from_numpy(arrays, source=source, name=name, digest=dataset_digest(arrays, {"file": uri}))
