"""A data-source plugin in one file: ``data/npz``, a caustic and its printed area in one NumPy
archive (``np.savez(path, caustic=(c, n, n) or (n, n), mask=(m, m))``).

    [project.entry-points."shape_from_caustics.data"]
    npz = "examples.plugins.npz_data:NpzData"

Chosen with ``data=npz data.path=caustic.npz data.delta=0.05`` (docs/plugins.md, "A newcomer's path").
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from framework.core.contracts.data_source import DataRequest, DataSource, PrintFacts
from framework.core.data import ReconstructionData
from operators.values import checked_number


class NpzData(DataSource):
    """The caustic ``caustic`` and the printed area ``mask`` of an .npz archive, as given.

    Args:
        path: The archive; relative to the run's base directory.
        delta: The relative noise level of the caustic, in (0, 1).
        volume: The deposited volume, scene units^3, or None when unknown.
    """

    def __init__(self, path: str | None = None, delta: float = 0.05, volume: float | None = None) -> None:
        if not path:
            raise ValueError("data=npz needs data.path=<archive .npz with arrays caustic and mask>")
        self.path, self.delta = (
            path,
            checked_number(delta, "data.delta", above=0.0, below=1.0, example="0.05 (5% noise)"),
        )
        self.volume = None if volume is None else checked_number(volume, "data.volume", above=0.0,
                                                                 unit="scene units^3, or null")

    def _arrays(self, request: DataRequest) -> tuple[torch.Tensor, torch.Tensor]:
        """(caustic (c, n, n) float64, mask (m, m) bool), read and checked against the request."""
        path = Path(self.path) if Path(self.path).is_absolute() else request.base_dir / self.path
        if not path.is_file():
            raise FileNotFoundError(
                f"data.path={str(path)!r} does not exist; write it with np.savez(path, caustic=..., mask=...)"
            )
        with np.load(path) as archive:
            missing = [key for key in ("caustic", "mask") if key not in archive.files]
            if missing:
                raise ValueError(
                    f"data.path={str(path)!r} lacks the array(s) {', '.join(missing)}; save caustic and mask"
                )
            caustic = torch.from_numpy(np.asarray(archive["caustic"], dtype=np.float64))
            mask = torch.from_numpy(np.asarray(archive["mask"]) > 0)
        caustic = caustic[None] if caustic.ndim == 2 else caustic
        if tuple(caustic.shape) != tuple(request.operator.output_shape):
            raise ValueError(f"data.path: caustic has shape {tuple(caustic.shape)}, the operator renders "
                             f"{tuple(request.operator.output_shape)}; set receiver.resolution to match")
        if tuple(mask.shape) != request.grid.shape:
            raise ValueError(f"data.path: mask has shape {tuple(mask.shape)}, the height grid is {request.grid.shape}; "
                             "set height_field.resolution to match")
        if not bool(torch.isfinite(caustic).all()):
            raise ValueError(f"data.path={str(path)!r}: caustic holds NaN or infinite values")
        return caustic, mask

    def check(self, request: DataRequest) -> PrintFacts:
        """The archive read and checked; its mask and the configured volume."""
        return PrintFacts(self._arrays(request)[1], self.volume)

    def load(self, request: DataRequest) -> ReconstructionData:
        """The caustic as the target, in the operator's dtype."""
        caustic, mask = self._arrays(request)
        return ReconstructionData(target=caustic.to(request.operator.dtype), mask=mask, volume=self.volume,
                                  delta=self.delta, source=str(self.path))
