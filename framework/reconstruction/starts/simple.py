"""Starts that need no data: flat glass, the configured design, a height-field file."""

from __future__ import annotations

from pathlib import Path

import torch

from framework.core.contracts.start import Start, StartRequest, StartResult
from framework.files.height_field_io import load_height_field
from framework.files.image_io import resolve_path
from operators.values import checked_number

__all__ = ["ZeroStart", "DesignStart", "FileStart"]


def _checked_shape(d: torch.Tensor, request: StartRequest, what: str) -> torch.Tensor:
    shape = request.problem.grid.shape
    if tuple(d.shape) != shape:
        raise ValueError(f"{what} gives heights of shape {tuple(d.shape)}, the reconstruction has {shape}; "
                         "set height_field.resolution to match")
    return d.to(request.problem.operator.dtype)


class ZeroStart(Start):
    """Flat glass, d0 = 0 (the paper's start). Plugin ``initial/zero``."""

    name = "zero"

    def __call__(self, request: StartRequest) -> StartResult:
        return StartResult(
            torch.zeros(request.problem.grid.shape, dtype=request.problem.operator.dtype), name=self.name
        )


class DesignStart(Start):
    """The print's design as the data carry it (a measured print's ``height_field.path``, the
    configured height field of synthetic data of another print, ``data.printed``) times ``scale``.
    Plugin ``initial/design``. Data without a design refuse it (:meth:`StartRequest.design`), and
    ``initial=auto`` skips it there (``reads_design``): never the truth of synthetic data."""

    name = "design"
    reads_design = True

    def __init__(self, scale: float = 1.0) -> None:
        self.scale = checked_number(scale, "initial.scale", 0.0, must="must be a finite number >= 0", example="0.5")

    def __call__(self, request: StartRequest) -> StartResult:
        d = request.design().double() * self.scale
        return StartResult(_checked_shape(d, request, "initial=design"), name=self.name, shaped=True)


class FileStart(Start):
    """A height field from ``path`` (.npy in scene units, or a 16-bit PNG, framework/files/height_field_io.py),
    resampled to the grid, times ``scale``. Plugin ``initial/file``."""

    name = "file"

    def __init__(self, path: str | None = None, scale: float = 1.0) -> None:
        if not isinstance(path, str) or not path:
            raise ValueError(f"initial.path={path!r}: give the height field to start from, e.g. "
                             "initial=file initial.path=outputs/<run>/height_field.npy")
        self.path = path
        self.scale = checked_number(scale, "initial.scale", 0.0, must="must be a finite number >= 0", example="0.5")

    def check(self, base_dir: Path) -> Path:
        """The file, which must exist (checked before the run opens)."""
        file = resolve_path(self.path, base_dir)
        if not file.is_file():
            raise FileNotFoundError(
                f"initial.path={self.path!r}: {file} does not exist; give a .npy or .png height field"
            )
        return file

    def __call__(self, request: StartRequest) -> StartResult:
        file = self.check(request.base_dir)
        d = torch.from_numpy(load_height_field(file, resolution=request.problem.grid.resolution, scale=self.scale))
        return StartResult(_checked_shape(d, request, f"initial.path={self.path!r}"), name=self.name, shaped=True)
