"""Parametric defects of a design, for the fit that sizes and names each defect
(framework/defects/fit.py; docs/method.md, "Defects against the design").

Every model changes the design c (m, m) near one place, in a frame of the design's feature there:
the unit vector ``along`` the feature, ``across`` it, the origin at the candidate's centre; lengths
in samples. A window W(t) along the feature (a box from t0 - L/2 to t0 + L/2 with tanh edges of
``EDGE`` samples) limits the change along it, a band from ``low`` to ``high`` across it (the
feature's own cross-section, framework/defects/fit.py ``frame_of``):

- ``modulation`` (t0, L, a): the design times 1 - a inside the window (a = 1: material missing,
  an interruption; 0 < a < 1: too low; a < 0: too high);
- ``shift`` (t0, L, s): the feature moved by s samples across itself inside the window;
- ``width`` (t0, L, w): the feature's cross-section stretched by 1 + w about its ridge;
- ``blob`` (x, y, V, r): a Gaussian drop of volume V (scene units^3) and radius r (samples) added,
  at most ``DROP_ASPECT`` r high (:func:`drop_volume`): a drop of molten glass wets the glass below
  it and stays lower than a hemisphere (a hemisphere of base radius R holds the volume of a Gaussian
  of radius r = R / 2 that peaks at 2.7 r); a taller, narrower spike is no drop a print makes.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

__all__ = ["Frame", "MODELS", "apply_model", "drop_volume"]

MODELS = ("modulation", "shift", "width", "blob")
EDGE = 1.0  # samples: the window's edge half-width
DROP_ASPECT = 2.0  # a drop's peak height is at most this many times its Gaussian radius
DROP_RADIUS = 0.3  # samples: a drop's radius at least


@dataclass(frozen=True)
class Frame:
    """Where a candidate sits: its centre (row, col) in samples, the feature's direction ``along``
    and normal ``across`` (row, col unit vectors), the ridge's offset across from the centre and the
    edges ``low`` < ``high`` of the changed band across the feature (samples, from the centre)."""

    row: float
    col: float
    along: tuple[float, float]
    across: tuple[float, float]
    ridge: float
    low: float
    high: float


def _coordinates(m: int, frame: Frame, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
    """(t, s): every sample's coordinate along and across the feature, samples, (m, m) each."""
    index = torch.arange(m, dtype=dtype)
    rows, cols = index[:, None] - frame.row, index[None, :] - frame.col
    t = rows * frame.along[0] + cols * frame.along[1]
    s = rows * frame.across[0] + cols * frame.across[1]
    return t, s


def _window(t: torch.Tensor, s: torch.Tensor, t0: float, length: float, frame: Frame) -> torch.Tensor:
    half = max(length, 0.0) / 2.0
    along = 0.5 * (torch.tanh((t - t0 + half) / EDGE) - torch.tanh((t - t0 - half) / EDGE))
    across = 0.5 * (torch.tanh((s - frame.low) / EDGE) - torch.tanh((s - frame.high) / EDGE))
    return along * across


def _sampled(design: torch.Tensor, rows: torch.Tensor, cols: torch.Tensor) -> torch.Tensor:
    """The design bilinearly interpolated at fractional sample positions (m, m) (clamped at the edge)."""
    m = design.shape[-1]
    grid = torch.stack((2.0 * cols / (m - 1) - 1.0, 2.0 * rows / (m - 1) - 1.0), dim=-1)[None]
    return F.grid_sample(design[None, None], grid.to(design.dtype), mode="bilinear", padding_mode="border",
                         align_corners=True)[0, 0]


def drop_volume(volume: float, radius: float, cell_area: float) -> float:
    """The volume (scene units^3) of a drop asked for ``volume`` with radius ``radius`` (samples,
    at least ``DROP_RADIUS``): capped where its peak would exceed ``DROP_ASPECT`` times the radius."""
    radius = max(radius, DROP_RADIUS)
    cap = DROP_ASPECT * radius * cell_area ** 0.5 * cell_area * 2.0 * torch.pi * radius ** 2
    return min(volume, cap)


def apply_model(design: torch.Tensor, frame: Frame, model: str, params: tuple[float, ...],
                cell_area: float) -> torch.Tensor:
    """The design with the defect ``model`` of ``params`` at ``frame``, shape (m, m), scene units."""
    m = design.shape[-1]
    t, s = _coordinates(m, frame, design.dtype)
    index = torch.arange(m, dtype=design.dtype)
    rows, cols = index[:, None].expand(m, m), index[None, :].expand(m, m)
    if model == "modulation":
        t0, length, a = params
        return design * (1.0 - a * _window(t, s, t0, length, frame))
    if model in ("shift", "width"):
        t0, length, amount = params
        window = _window(t, s, t0, length, frame)
        if model == "shift":
            back = amount * window
        else:
            back = (s - frame.ridge) * (1.0 - 1.0 / (1.0 + amount)) * window
        return _sampled(design, rows - back * frame.across[0], cols - back * frame.across[1])
    if model == "blob":
        row, col, volume, radius = params
        volume, radius = drop_volume(volume, radius, cell_area), max(radius, DROP_RADIUS)
        r2 = (rows - row) ** 2 + (cols - col) ** 2
        peak = volume / (cell_area * 2.0 * torch.pi * radius ** 2)
        return design + peak * torch.exp(-r2 / (2.0 * radius ** 2))
    raise ValueError(f"defect model {model!r}; use one of {', '.join(MODELS)}")
