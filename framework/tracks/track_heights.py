"""Tracks as a representation: the beads' profiles, the drops and a coarse residual grid rendered
onto the heights grid, d = R(theta), with the exact vector-Jacobian product.

theta holds, in scene units, for each track its height, width and offset at its knots, its
cross-section's shape and its gaps (centre's arc length, length; a closed gap is 0 long), then
each drop's (x, y, radius, height), then a residual grid of (m_r, m_r) samples spread over the
heights grid by bilinear interpolation (what beads cannot express: sagging, smeared glass). The
paths stay fixed; the samples near them and their path coordinates are computed once
(framework/tracks/geometry.py), so a render is a gather, an elementwise bead formula and a
scatter-add, and J^T g is the same computation's reverse pass (torch autograd: exact, no finite
differences).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch
from scipy import ndimage
import torch.nn.functional as F  # noqa: N812
from torch import Tensor

from framework.core.contracts.representation import Representation, SearchContext
from framework.tracks.geometry import PathSamples, path_samples, resampled_path
from framework.tracks.search_sites import DropSite, Window, drop_sites, pixels_beneath, windows_of
from framework.tracks.track_search import SearchSettings, TrackMoves, search_tracks
from framework.tracks.track_set import (GAP_EDGE_MM, SECTION_REACH, SECTION_SAMPLES, SHAPE_RANGE, Drop, Track,
                                       TrackSet)

__all__ = ["TrackSettings", "TrackHeights"]

LN2 = math.log(2.0)
TAIL = 1.6  # the bead is drawn out to TAIL x its widest allowed width (a Gaussian's exp(-ln 2 (2 TAIL)^2) < 1e-3)
DROP_MM = 3.0  # drop sites at least DROP_MM apart, each judged on the receiver pixels within DROP_MM / 2
EDGE = 1e-4  # the bead's edge is rounded over 1 - v^2 / c^2 < EDGE (an ellipse's slope stays finite there)


@dataclass(frozen=True)
class TrackSettings:
    """How far the fit may move a track from its nominal profiles, and its priors (mm where a length).

    Attributes:
        knot_mm: Spacing of the profiles' knots along each path.
        max_offset_mm: The farthest a bead may move across its path.
        width_range: (low, high) factors of its own nominal widths a bead's width may take.
        height_factor: The highest a bead may rise, times the highest nominal height.
        residual_mm: Spacing of the residual grid's samples (0: no residual grid).
        smoothness: Weight of the profiles' first differences (in their scales), relative to the data term.
        residual_sparsity: Weight of the residual grid's smoothed L1 norm, relative to the data term.
        spare_drops: Drops the global search may place where the photo shows glass off the beads (0: none;
            docs/results.md, "Prints of beads").
        gaps: Gaps (interruptions) each track may open, besides its nominal ones.
    """

    knot_mm: float = 1.0
    max_offset_mm: float = 1.5
    width_range: tuple[float, float] = (0.25, 2.5)
    height_factor: float = 3.0
    residual_mm: float = 1.0
    smoothness: float = 1.0e-4
    residual_sparsity: float = 1.0e-2
    spare_drops: int = 0
    gaps: int = 0


@dataclass(frozen=True)
class _Layout:
    """Where one track's parameters sit in theta, and its samples' knot interpolation."""

    start: int
    knots: int
    gaps: int
    samples: PathSamples
    index: Tensor
    left: Tensor
    frac: Tensor
    u: Tensor
    beyond: Tensor
    section: Tensor | None
    arc: Tensor  # (p,) the samples' arc lengths along the path

    @property
    def gap_start(self) -> int:
        """The index in theta of its first gap's centre (each gap: centre, length)."""
        return self.start + 3 * self.knots + 1


def _tensor(array: np.ndarray, dtype: torch.dtype) -> Tensor:
    return torch.from_numpy(np.ascontiguousarray(array)).to(dtype)


def _sampled(section: Tensor, squared: Tensor) -> Tensor:
    """A measured section (SECTION_SAMPLES over v in [0, SECTION_REACH]) at v = sqrt(squared), linear
    between its samples, 0 beyond."""
    step = SECTION_REACH / (SECTION_SAMPLES - 1)
    at = (torch.sqrt(squared + 1e-30) / step).clamp(max=SECTION_SAMPLES - 1.0)
    left = at.detach().floor().clamp(max=SECTION_SAMPLES - 2.0)
    frac = at - left
    i = left.long()
    return section[i] * (1.0 - frac) + section[i + 1] * frac


class TrackHeights(Representation):
    """d = R(theta) for a set of tracks on an (m, m) grid over [-W, W]^2.

    Args:
        tracks: The nominal print (mm): the start theta_0 (the design's profiles).
        resolution: m.
        half_width: W, scene units.
        mm_per_unit: One scene unit in mm.
        settings: :class:`TrackSettings`.
        dtype: torch dtype of theta and d.
        source: Where the tracks came from, in words (reports).
        mask: (m, m) bool, the printed area: residual samples away from it stay 0 (None: everywhere).
        search: The global search's settings (framework/tracks/track_search.py).
    """

    describes_beads = True

    def __init__(self, tracks: TrackSet, resolution: int, half_width: float, mm_per_unit: float,
                 settings: TrackSettings = TrackSettings(), dtype: torch.dtype = torch.float64,
                 source: str = "given", mask: np.ndarray | None = None,
                 search: SearchSettings | None = None) -> None:
        self.source, self.search_settings = source, search or SearchSettings()
        self.correction: Tensor | None = None  # (m, m) added to every render: what the beads miss of the design
        self._windows: tuple[tuple[float, int], list[Window]] | None = None
        self.shape = (int(resolution), int(resolution))
        self.dtype, self.settings = dtype, settings
        self.half_width, self.mm = float(half_width), float(mm_per_unit)
        self.cell = 2.0 * self.half_width / (resolution - 1)
        self.gap_edge = max(GAP_EDGE_MM / float(mm_per_unit), 0.25 * self.cell)
        self.nominal = tracks.with_knot_spacing(settings.knot_mm)
        widest = max(float(t.width.max()) for t in self.nominal.tracks) / self.mm
        self.highest = max(float(t.height.max()) for t in self.nominal.tracks) / self.mm
        self.width_bounds = (max(settings.width_range[0] * widest, 0.5 * self.cell), settings.width_range[1] * widest)
        shifted = max(float(np.abs(t.offset).max()) for t in self.nominal.tracks) / self.mm
        reach = shifted + settings.max_offset_mm / self.mm + TAIL * self.width_bounds[1]
        self._layouts: list[_Layout] = []
        start = 0
        for track in self.nominal.tracks:
            path = resampled_path(track.path / self.mm, 0.25 * self.cell)
            samples = path_samples(path, self.half_width, resolution, reach)
            spacing = samples.length / (track.knots - 1)
            position = np.clip(samples.s / spacing, 0.0, track.knots - 1.0)
            left = np.minimum(np.floor(position).astype(np.int64), track.knots - 2)
            gaps = len(track.gaps) + settings.gaps
            self._layouts.append(_Layout(start, track.knots, gaps, samples, torch.from_numpy(samples.index),
                                         torch.from_numpy(left), _tensor(position - left, dtype),
                                         _tensor(samples.u, dtype), _tensor(samples.beyond, dtype),
                                         None if track.section is None else _tensor(track.section, dtype),
                                         _tensor(samples.s, dtype)))
            start += 3 * track.knots + 1 + 2 * gaps
        self.drops_start = start
        self.spare_start = start + 4 * len(self.nominal.drops)  # drop slots the search may place, parked at 0 high
        self.residual_start = self.spare_start + 4 * settings.spare_drops
        self.residual_side = 0 if settings.residual_mm <= 0 else max(
            2, int(round(2.0 * self.half_width * self.mm / settings.residual_mm)) + 1)
        self.size = self.residual_start + self.residual_side**2
        self._residual_free = self._near_mask(mask)

    def _near_mask(self, mask: np.ndarray | None) -> Tensor:
        """(m_r^2,) bool: residual samples within one of their spacings of the printed area."""
        if mask is None or not self.residual_side:
            return torch.ones(self.residual_side**2, dtype=torch.bool)
        m = self.shape[0]
        reach = int(np.ceil((m - 1) / max(self.residual_side - 1, 1)))
        grown = ndimage.binary_dilation(np.asarray(mask, dtype=bool), iterations=reach)
        nodes = np.round(np.linspace(0, m - 1, self.residual_side)).astype(int)
        return torch.from_numpy(grown[np.ix_(nodes, nodes)].reshape(-1).copy())

    # -- parameters -------------------------------------------------------------------------------
    def _track_values(self, track: Track) -> list[np.ndarray]:
        """Its parameters: profiles, shape, then its gaps (its nominal ones, then closed ones at its middle:
        a length below 0 cuts nothing and has no gradient, so only the global search opens a gap)."""
        closed = [(0.5 * track.length, -GAP_EDGE_MM)] * self.settings.gaps
        gaps = np.array([*track.gaps, *closed], dtype=np.float64).reshape(-1) / self.mm
        return [track.height / self.mm, track.width / self.mm, track.offset / self.mm, np.array([track.shape]), gaps]

    def initial(self) -> Tensor:
        parts = [v for t in self.nominal.tracks for v in self._track_values(t)]
        parts += [np.array([d.x, d.y, d.radius, d.height]) / np.array([self.mm, self.mm, self.mm, self.mm])
                  for d in self.nominal.drops]
        parts += [np.array([-self.half_width, -self.half_width, self.cell, 0.0])] * self.settings.spare_drops
        parts.append(np.zeros(self.residual_side**2))
        return _tensor(np.concatenate(parts), self.dtype)

    def _per_track(self, values: tuple[float, float, float, float, float, float]) -> Tensor:
        """Every track's (height, width, offset, shape, gap centre, gap length) entries set to ``values``."""
        out = torch.empty(self.size, dtype=self.dtype)
        for layout in self._layouts:
            k, s, g = layout.knots, layout.start, layout.gap_start
            out[s:s + k], out[s + k:s + 2 * k], out[s + 2 * k:s + 3 * k], out[s + 3 * k] = values[:4]
            out[g:g + 2 * layout.gaps:2], out[g + 1:g + 2 * layout.gaps:2] = values[4:]
        return out

    def bounds(self) -> tuple[Tensor, Tensor]:
        """Heights in [0, height_factor x the highest nominal]; each track's widths in width_range x
        its own nominal ones (half a cell at least); offsets within max_offset_mm of the nominal;
        shapes in SHAPE_RANGE; gaps on their path; drops near their start, spare ones anywhere; the
        residual near the printed area."""
        settings, w = self.settings, self.width_bounds
        offset, top = settings.max_offset_mm / self.mm, settings.height_factor * self.highest
        lower = self._per_track((0.0, w[0], -offset, SHAPE_RANGE[0], 0.0, -GAP_EDGE_MM / self.mm))
        upper = self._per_track((top, w[1], offset, SHAPE_RANGE[1], 0.0, 0.0))
        start = self.initial()
        for track, layout in zip(self.nominal.tracks, self._layouts):
            k, s = layout.knots, layout.start
            narrowest, widest = float(track.width.min()) / self.mm, float(track.width.max()) / self.mm
            lower[s + k:s + 2 * k] = min(max(settings.width_range[0] * narrowest, 0.5 * self.cell), narrowest)
            upper[s + k:s + 2 * k] = settings.width_range[1] * widest
            upper[s:s + k] = max(top, float(track.height.max()) / self.mm)
            lower[s + 2 * k:s + 3 * k] += start[s + 2 * k:s + 3 * k]
            upper[s + 2 * k:s + 3 * k] += start[s + 2 * k:s + 3 * k]
            upper[layout.gap_start:layout.gap_start + 2 * layout.gaps] = track.length / self.mm
        for i, drop in enumerate(self.nominal.drops):
            j, near = self.drops_start + 4 * i, settings.max_offset_mm / self.mm
            x, y = drop.x / self.mm, drop.y / self.mm
            lower[j:j + 4] = torch.tensor([x - near, y - near, self.cell, 0.0], dtype=self.dtype)
            upper[j:j + 4] = torch.tensor([x + near, y + near, w[1], top], dtype=self.dtype)
        for j in range(self.spare_start, self.residual_start, 4):
            lower[j:j + 4] = torch.tensor([-self.half_width, -self.half_width, self.cell, 0.0], dtype=self.dtype)
            upper[j:j + 4] = torch.tensor([self.half_width, self.half_width, w[1], top], dtype=self.dtype)
        residual = top * self._residual_free.to(self.dtype)
        lower[self.residual_start:], upper[self.residual_start:] = -residual, residual
        return lower, upper

    def scale(self) -> Tensor:
        widest = self.width_bounds[1] / self.settings.width_range[1]
        out = self._per_track((self.highest, widest, 0.5 * widest, 1.0, widest, widest))
        for j in range(self.drops_start, self.residual_start, 4):
            out[j:j + 4] = torch.tensor([widest, widest, widest, self.highest], dtype=self.dtype)
        out[self.residual_start:] = 0.25 * self.highest
        return out

    def stages(self) -> list[Tensor]:
        beads = torch.zeros(self.size, dtype=torch.bool)
        beads[:self.residual_start] = True
        return [beads] if self.residual_side == 0 else [beads, torch.ones(self.size, dtype=torch.bool)]

    # -- rendering ----------------------------------------------------------------------------------
    def _render(self, theta: Tensor) -> Tensor:
        m = self.shape[0]
        flat = torch.zeros(m * m, dtype=theta.dtype)
        for layout in self._layouts:
            k, s, i, f = layout.knots, layout.start, layout.left, layout.frac

            def along(first: int) -> Tensor:
                values = theta[first:first + k]  # noqa: B023 (used at once)
                return values[i] * (1.0 - f) + values[i + 1] * f  # noqa: B023

            height, width, offset = along(s), along(s + k), along(s + 2 * k)
            shape = theta[s + 3 * k]
            g = layout.gap_start
            for centre, length in theta[g:g + 2 * layout.gaps].reshape(-1, 2):  # cut: 1 inside a gap, 0 outside
                length = length.clamp(min=0.0)
                cut = (torch.sigmoid((layout.arc - centre + 0.5 * length) / self.gap_edge)
                       - torch.sigmoid((layout.arc - centre - 0.5 * length) / self.gap_edge))
                height = height * (1.0 - cut)
            squared = 4.0 * ((layout.u - offset) ** 2 + layout.beyond**2) / width**2  # v^2 = (2 r / width)^2
            if layout.section is not None:
                flat = flat.index_add(0, layout.index, height * _sampled(layout.section, squared))
                continue
            power = 1.0 / shape
            inside = 1.0 - squared * -torch.expm1(-LN2 * shape)  # 1 - v^2 / c^2
            # ((inside+ + E)^p - E^p) / ((1 + E)^p - E^p): continuous, 0 at the edge, 1 on the centre line
            edge = EDGE**power
            bead = ((inside.clamp(min=0.0) + EDGE) ** power - edge) / ((1.0 + EDGE) ** power - edge)
            flat = flat.index_add(0, layout.index, height * bead)
        d = flat.reshape(m, m)
        if self.residual_start > self.drops_start:
            axis = torch.linspace(-self.half_width, self.half_width, m, dtype=theta.dtype)
            for j in range(self.drops_start, self.residual_start, 4):
                x, y, radius, height = theta[j:j + 4]
                d = d + height * torch.exp(-((axis[None, :] - x) ** 2 + (axis[:, None] - y) ** 2) / (2 * radius**2))
        if self.residual_side:
            coarse = theta[self.residual_start:].reshape(1, 1, self.residual_side, self.residual_side)
            d = d + F.interpolate(coarse, size=self.shape, mode="bilinear", align_corners=True)[0, 0]
        return d if self.correction is None else d + self.correction.to(d.dtype)

    def drawn(self, theta: Tensor) -> Tensor:
        """R(theta) (m, m) with torch's autograd graph (for a caller's own loss)."""
        return self._render(theta)

    def heights(self, theta: Tensor) -> Tensor:
        with torch.no_grad():
            return self._render(theta.to(self.dtype))

    def vjp(self, theta: Tensor, g: Tensor) -> Tensor:
        with torch.enable_grad():
            at = theta.detach().to(self.dtype).requires_grad_(True)
            (grad,) = torch.autograd.grad(self._render(at), at, g.to(self.dtype))
        return grad

    # -- prior ----------------------------------------------------------------------------------------
    def prior(self, theta: Tensor) -> tuple[float, Tensor]:
        """Smooth profiles (first differences along each path, in their scales) and a sparse residual
        (a smoothed L1 norm per residual sample), both divided by the cell area like the data term
        (framework/core/objective.py), so that their weights are shares of it."""
        with torch.enable_grad():
            at = theta.detach().to(self.dtype).requires_grad_(True)
            scale, area = self.scale(), self.cell**2
            value = at.new_zeros(())
            for layout in self._layouts:
                k, s = layout.knots, layout.start
                steps = torch.diff(at[s:s + 3 * k].reshape(3, k), dim=1) / scale[s:s + 3 * k].reshape(3, k)[:, 1:]
                value = value + 0.5 * self.settings.smoothness * torch.sum(steps**2) / area
            if self.residual_side:
                r = at[self.residual_start:] / scale[self.residual_start:]
                count = float(self.residual_side**2)
                value = value + self.settings.residual_sparsity * torch.sum(torch.sqrt(r**2 + 1e-4) - 1e-2) / (
                    area * count)
            (grad,) = torch.autograd.grad(value, at)
        return float(value.detach()), grad

    # -- reading a fit ------------------------------------------------------------------------------
    def track_set(self, theta: Tensor) -> TrackSet:
        """The fitted print (mm) at theta (the shapes kept in SHAPE_RANGE against float32 rounding); the
        spare drops the search placed among its drops."""
        values = theta.detach().cpu().double().numpy() * self.mm
        tracks = []
        for track, layout in zip(self.nominal.tracks, self._layouts):
            k, s = layout.knots, layout.start
            shape = float(np.clip(values[s + 3 * k] / self.mm, *SHAPE_RANGE))
            g = layout.gap_start
            gaps = tuple((float(c), float(n)) for c, n in values[g:g + 2 * layout.gaps].reshape(-1, 2) if n > 0.0)
            tracks.append(replace(track, height=values[s:s + k], width=values[s + k:s + 2 * k],
                                  offset=values[s + 2 * k:s + 3 * k], shape=shape, gaps=gaps))
        drops = tuple(Drop(*(float(v) for v in values[j:j + 4])) for j in range(self.drops_start, self.spare_start, 4))
        return TrackSet(tuple(tracks), drops + tuple(drop for _, drop in self.placed_drops(theta)))

    def placed_drops(self, theta: Tensor) -> list[tuple[int, Drop]]:
        """The drops the search placed (spare slots above 0 high): (their index in theta, the drop in mm)."""
        values = theta.detach().cpu().double().numpy()
        return [(j, Drop(*(float(v) * self.mm for v in values[j:j + 4])))
                for j in range(self.spare_start, self.residual_start, 4) if values[j + 3] > 0.0]

    def residual(self, theta: Tensor) -> Tensor:
        """The residual grid's contribution to the heights (m, m), scene units (zeros without one)."""
        if not self.residual_side:
            return torch.zeros(self.shape, dtype=self.dtype)
        coarse = theta.detach()[self.residual_start:].reshape(1, 1, self.residual_side, self.residual_side)
        return F.interpolate(coarse.to(self.dtype), size=self.shape, mode="bilinear", align_corners=True)[0, 0]

    def search(self, theta: Tensor, context: SearchContext) -> tuple[Tensor, list[str]]:
        """Each track's worst-explained windows searched over alternative cross-sections, and glass
        tried at the misfit's peaks (framework/tracks/track_search.py)."""
        windows = self._search_windows(context.receiver_half_width, context.receiver_pixels)
        widths = [float(t.width.mean()) / self.mm for t in self.nominal.tracks]
        bead = float(np.mean([t.height.mean() for t in self.nominal.tracks])) / self.mm
        settings = self.search_settings
        spacings = [layout.samples.length / (layout.knots - 1) for layout in self._layouts]
        moves = TrackMoves(self.profile_slices, widths, [f * bead for f in settings.drop_heights],
                           [f * float(np.mean(widths)) for f in settings.drop_radii], spacings,
                           lambda track: self.gap_slots(track) if context.earlier else [])
        free = [j for j in range(self.spare_start, self.residual_start, 4) if float(theta[j + 3]) <= 0.0]

        def drops(misfit: np.ndarray) -> list[DropSite]:
            return drop_sites(misfit / context.noise_variance, context.receiver_half_width, context.receiver_pixels,
                              free[:settings.drop_sites], DROP_MM / self.mm)

        return search_tracks(theta, windows, drops, moves, self.clipped, context.objective, context.pixel_misfit,
                             context.penalty, context.noise_variance, settings)

    def _search_windows(self, receiver_half_width: float, pixels: int) -> list[Window]:
        key = (receiver_half_width, pixels)
        if self._windows is None or self._windows[0] != key:
            per_track = [(layout.knots, layout.left.numpy() + layout.frac.numpy(),
                          pixels_beneath(layout.samples.index, self.shape[0], self.half_width, receiver_half_width,
                                         pixels)) for layout in self._layouts]
            self._windows = (key, windows_of(per_track, self.search_settings.knots))
        return self._windows[1]

    def profile_slices(self, track: int) -> tuple[slice, slice, slice]:
        """Where track ``track``'s height, width and offset knots sit in theta (its gaps: :meth:`gap_slots`)."""
        layout = self._layouts[track]
        k, s = layout.knots, layout.start
        return slice(s, s + k), slice(s + k, s + 2 * k), slice(s + 2 * k, s + 3 * k)

    def gap_slots(self, track: int) -> list[int]:
        """The indices in theta of the centres (each followed by its length) of the gaps track ``track``
        may open beyond its nominal ones."""
        layout = self._layouts[track]
        return [layout.gap_start + 2 * j for j in range(len(self.nominal.tracks[track].gaps), layout.gaps)]

    def residual_indices(self, where: np.ndarray) -> Tensor:
        """The indices in theta of the residual samples nearest the heights samples ``where`` (m, m) bool."""
        rows, cols = np.nonzero(where)
        factor = (self.residual_side - 1) / (self.shape[0] - 1)
        coarse = np.unique(np.round(rows * factor).astype(int) * self.residual_side
                           + np.round(cols * factor).astype(int))
        return torch.from_numpy(self.residual_start + coarse)

    def summary(self, theta: Tensor) -> dict[str, Any]:
        return {"representation": "tracks", "parameters": self.size, "tracks": len(self.nominal.tracks),
                "drops": len(self.track_set(theta).drops), "residual_grid": self.residual_side}
