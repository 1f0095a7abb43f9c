"""Each candidate sized and named by the defect model that explains the caustic best
(docs/method.md, "Defects against the design").

For a candidate (framework/defects/regions.py) the four models of framework/defects/models.py are
fitted to the photo, each added to the heights that explain the photo so far (the design with the
defects already found, framework/defects/pursuit.py), by Nelder-Mead on the misfit
||F(base + defect) - b||_W^2: a feature model from the best point of a linearised scan of its place and
length (:func:`_feature_start`), a drop from starts read off the candidate's deviation. The evidence of the best
model is the misfit it removes in units of the pixel noise variance s^2:
E = (||F(base) - b||^2 - ||F(base + defect) - b||^2) / s^2. When the photo needs no defect there, E of
a k-parameter model is about a chi-square with k degrees of freedom (a few units).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
import torch

from framework.defects.models import MODELS, Frame, apply_model, drop_volume
from framework.defects.regions import Candidate

if TYPE_CHECKING:
    from scipy.optimize import OptimizeResult

__all__ = ["Defect", "Fit", "KINDS", "Misfit", "candidate_frames", "chance_of", "fit_candidate", "frame_of",
           "refit"]

KINDS = ("interruption", "too_low", "too_high", "excess", "too_wide", "too_narrow", "displaced")
INTERRUPTED = 0.5  # a feature lowered or narrowed by at least this fraction of its glass is interrupted
FEATURE_MM = 6.0  # a feature's ridge is sought this far across from a candidate's centre (mm)
BAND_FALL = 0.1  # a feature ends across where the design falls below this share of its ridge (or rises by it)
BAND_MARGIN_MM = 1.0  # the changed band reaches this far beyond ...
BAND_MM = 8.0  # ... and at most this far from the ridge
COHERENT = 0.5  # a design with a structure-tensor coherence below this has no direction of its own there
OBLIQUE_DEG = 20.0  # a deviation's long axis this far from the design's direction gives frames of its own
SCAN_POSITIONS = 15  # a feature model's start is sought at up to this many places along the feature ...
SCAN_LENGTHS_MM = (1.0, 3.0, 8.0)  # ... with each of these lengths
PROBES = {"modulation": 0.3, "width": 0.3}  # the amount whose image change is scaled; a shift's: 0.5 mm


class Misfit(Protocol):
    """The data term of heights h (m, m): ``misfit(h)`` = ||F(h) - b||_W^2, ``residual(h)`` =
    sqrt(w) (F(h) - b), the image it sums, and ``gradient(h)`` (m, m), its gradient in h."""

    def __call__(self, heights: torch.Tensor) -> float: ...

    def residual(self, heights: torch.Tensor) -> torch.Tensor: ...

    def gradient(self, heights: torch.Tensor) -> torch.Tensor: ...


@dataclass(frozen=True)
class Defect:
    """One defect, lengths in mm, volumes in mm^3.

    Attributes:
        kind: One of :data:`KINDS`. x_mm, y_mm: its centre on the substrate.
        length_mm: Its extent along the design's feature (a drop: its diameter, 2.355 r).
        size: The kind's own measure: interruption / too_low / too_high: the fraction of the design's
            glass missing (negative: added; an interruption: lowered or narrowed); too_wide /
            too_narrow: the relative change of the feature's width; displaced: the shift in mm;
            excess: the volume in mm^3.
        peak_mm: The largest height change (signed). volume_mm3: The glass added (negative: missing).
        evidence: The misfit removed, in pixel noise variances. confidence: see the module.
        model: The defect model fitted, params: its parameters (samples, scene units).
    """

    kind: str
    x_mm: float
    y_mm: float
    length_mm: float
    size: float
    peak_mm: float
    volume_mm3: float
    evidence: float
    confidence: float
    model: str
    params: tuple[float, ...]

    def as_dict(self) -> dict[str, object]:
        out = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in asdict(self).items()}
        out["params"] = [round(float(p), 5) for p in self.params]
        return out


def frame_of(design: np.ndarray, candidate: Candidate, cell_mm: float,
             along: tuple[float, float] | None = None) -> Frame:
    """The candidate's frame: its centre, the feature's direction ``along`` (by default the design's
    there: the structure tensor's eigenvector of least change; along the columns where the design is
    flat), the ridge (the design's maximum across within ``FEATURE_MM`` of the centre) and the band
    of the feature's cross-section (:func:`_band`)."""
    row, col = candidate.centre
    reach = FEATURE_MM / cell_mm
    along = np.asarray(_design_direction(design, row, col, reach)[0] if along is None else along, dtype=float)
    across = np.array([-along[1], along[0]])
    offsets = np.arange(-reach, reach + 0.25, 0.5)
    ridge = float(offsets[int(np.argmax(_across(design, row, col, across, offsets)))])
    low, high = _band(design, row, col, across, ridge, cell_mm)
    return Frame(row, col, (float(along[0]), float(along[1])), (float(across[0]), float(across[1])), ridge, low, high)


def _across(design: np.ndarray, row: float, col: float, across: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """The design at ``offsets`` (samples) across from (row, col), nearest samples, clamped to the grid."""
    m = design.shape[0]
    return design[np.clip(np.round(row + offsets * across[0]).astype(int), 0, m - 1),
                  np.clip(np.round(col + offsets * across[1]).astype(int), 0, m - 1)]


def _design_direction(design: np.ndarray, row: float, col: float, reach: float) -> tuple[tuple[float, float], float]:
    """The design's direction of least change within ``reach`` samples of (row, col) (the structure
    tensor's eigenvector; along the columns where the design is flat) and its coherence
    (l1 - l2) / (l1 + l2) in [0, 1]: 0 where the design changes alike in every direction (a round bump)."""
    gr, gc = np.gradient(design)
    r0, c0 = max(int(row - reach), 0), max(int(col - reach), 0)
    r1, c1 = int(row + reach) + 1, int(col + reach) + 1
    a, b = gr[r0:r1, c0:c1], gc[r0:r1, c0:c1]
    tensor = np.array([[np.sum(a * a), np.sum(a * b)], [np.sum(a * b), np.sum(b * b)]])
    if np.trace(tensor) <= 1e-30:
        return (0.0, 1.0), 0.0
    values, vectors = np.linalg.eigh(tensor)
    return (float(vectors[0, 0]), float(vectors[1, 0])), float((values[1] - values[0]) / (values[1] + values[0]))


def _band(design: np.ndarray, row: float, col: float, across: np.ndarray, ridge: float, cell_mm: float
          ) -> tuple[float, float]:
    """The edges across (samples from the centre) of the feature whose ridge lies ``ridge`` across
    from (row, col): on each side where the design falls below ``BAND_FALL`` of the ridge's height or
    rises again by that much toward another feature, plus ``BAND_MARGIN_MM``, at most ``BAND_MM``
    from the ridge; +-``FEATURE_MM`` about the centre where the design has no ridge there."""
    steps = np.arange(0.0, BAND_MM / cell_mm + 0.25, 0.5)
    top = float(_across(design, row, col, across, np.array([ridge]))[0])
    if top <= 0.0:
        return -FEATURE_MM / cell_mm, FEATURE_MM / cell_mm
    edges = []
    for sign in (-1.0, 1.0):
        profile = _across(design, row, col, across, ridge + sign * steps)
        ends = (profile < BAND_FALL * top) | (profile > np.minimum.accumulate(profile) + BAND_FALL * top)
        reach = steps[int(np.argmax(ends))] if ends.any() else steps[-1]
        edges.append(ridge + sign * min(reach + BAND_MARGIN_MM / cell_mm, BAND_MM / cell_mm))
    return edges[0], edges[1]


def candidate_frames(design: np.ndarray, candidate: Candidate, cell_mm: float) -> list[Frame]:
    """The frames a feature model is tried in: the design's (:func:`frame_of`); where the candidate's
    deviation is elongated (its |e|-weighted spread at least twice as long as wide) and its long axis
    oblique to the design's direction (by more than ``OBLIQUE_DEG``), also frames along and across
    that axis, instead of the design's where the design has no direction there (coherence below
    ``COHERENT``: a round bump): a defect runs along or across its feature, and the deviation shows which."""
    row, col = candidate.centre
    along, coherence = _design_direction(design, row, col, FEATURE_MM / cell_mm)
    frames = [frame_of(design, candidate, cell_mm, along)]
    w = np.abs(candidate.e)
    if candidate.rows.size < 3 or float(w.sum()) <= 0.0:
        return frames
    points = np.stack([candidate.rows, candidate.cols], axis=1).astype(float)
    centred = points - (w[:, None] * points).sum(axis=0) / w.sum()
    values, vectors = np.linalg.eigh((w[:, None, None] * centred[:, :, None] * centred[:, None, :]).sum(axis=0))
    if values[1] <= 0.0 or values[0] > 0.25 * values[1]:  # the spread's lengths go as the square roots
        return frames
    axis = vectors[:, 1]
    own = [frame_of(design, candidate, cell_mm, (float(axis[0]), float(axis[1]))),
           frame_of(design, candidate, cell_mm, (float(-axis[1]), float(axis[0])))]
    if coherence < COHERENT:
        return own
    angle = math.degrees(math.acos(min(abs(float(axis @ np.array(along))), 1.0)))
    return frames + own if OBLIQUE_DEG < angle < 90.0 - OBLIQUE_DEG else frames


def _drop_starts(design: np.ndarray, candidate: Candidate, cell_area: float) -> list[np.ndarray]:
    """A drop's trial starts (row, col, log V, log r): where the most glass was added, with that volume
    and three radii (at least a 3 x 3 sample drop at 5% of the design's peak: a drop the reconstruction
    smeared out still gets a start that moves)."""
    added = candidate.e > 0
    volume = max(float(candidate.e[added].sum()) * cell_area, 0.45 * float(design.max()) * cell_area, 1e-12)
    k = int(np.argmax(np.where(added, candidate.e, -np.inf))) if added.any() else int(np.argmax(np.abs(candidate.e)))
    row, col = float(candidate.rows[k]), float(candidate.cols[k])
    return [np.array([row, col, math.log(v), math.log(r)]) for v in (volume, 3.0 * volume, volume / 3.0)
            for r in (0.8, 1.2, 1.8)]


def _feature_start(misfit: Misfit, base: torch.Tensor, frame: Frame, model: str, candidate: Candidate,
                   cell_mm: float, cell_area: float) -> tuple[np.ndarray, float]:
    """A feature model's start (t0, L, amount) and its linearised misfit: over a grid of places t0
    along the candidate's extent along the feature (samples), lengths L and a probe amount p of either
    sign, the image change g of p scaled by least squares against the residual r (amount = k p,
    k = -<g, r> / <g, g> >= 0, within the model's limits); the (t0, L, amount) whose linearised misfit
    ||r + k g||^2 is least. The caustic
    is far from linear in the amount (raising a line moves its focus otherwise than lowering it), so
    each sign gets its own probe; the sign and size of the amount come out of the photo."""
    r0 = misfit.residual(base)
    probe = PROBES.get(model, 0.5 / cell_mm)
    t = (candidate.rows - frame.row) * frame.along[0] + (candidate.cols - frame.col) * frame.along[1]
    low, high = min(float(t.min()), -3.0), max(float(t.max()), 3.0)
    places = np.linspace(low, high, int(min(np.floor(high - low) + 1, SCAN_POSITIONS)))
    (_, _), (_, _), (amount_low, amount_high) = LIMITS[model]
    best, best_value = np.array([0.0, SCAN_LENGTHS_MM[0] / cell_mm, probe]), math.inf
    for t0 in places:
        for length_mm in SCAN_LENGTHS_MM:
            length = length_mm / cell_mm
            for signed in (probe, -probe):
                g = misfit.residual(apply_model(base, frame, model, (float(t0), length, signed), cell_area)) - r0
                gg = float((g * g).sum())
                if gg <= 0.0:
                    continue
                k = max(-float((g * r0).sum()) / gg, 0.0)
                amount = float(np.clip(k * signed, amount_low, amount_high))
                value = float(((r0 + (amount / signed) * g) ** 2).sum())
                if value < best_value:
                    best, best_value = np.array([float(t0), length, amount]), value
    return best, best_value


# Simplex steps and limits of each model's parameters; a drop's volume and radius as logarithms.
STEPS = {
    "modulation": (1.0, 1.0, 0.25),
    "shift": (1.0, 1.0, 0.7),
    "width": (1.0, 1.0, 0.2),
    "blob": (1.0, 1.0, 0.7, 0.3),
}
LIMITS = {"modulation": ((-40, 40), (0.5, 80), (-1.5, 1.0)), "shift": ((-40, 40), (0.5, 80), (-8.0, 8.0)),
          "width": ((-40, 40), (0.5, 80), (-0.8, 2.0)),
          "blob": ((-1e9, 1e9), (-1e9, 1e9), (-60.0, 0.0), (math.log(0.5), math.log(8.0)))}


def _model_params(model: str, p: np.ndarray) -> tuple[float, ...]:
    """The model's parameters from the optimiser's, within the model's limits (a drop's volume and
    radius from their logarithms)."""
    q = tuple(float(np.clip(v, lo, hi)) for v, (lo, hi) in zip(p, LIMITS[model]))
    return (q[0], q[1], math.exp(q[2]), math.exp(q[3])) if model == "blob" else q


def _nelder_mead(objective: Callable[[np.ndarray], float], x0: np.ndarray, steps: np.ndarray, evaluations: int,
                 base_misfit: float) -> OptimizeResult:
    """Nelder-Mead from ``x0`` on the simplex of ``steps``, at most ``evaluations`` misfits."""
    from scipy import optimize  # scipy.optimize and .stats take ~1 s to import: only when defects are fitted
    simplex = np.vstack([x0] + [x0 + np.eye(len(x0))[i] * steps[i] for i in range(len(x0))])
    return optimize.minimize(objective, x0, method="Nelder-Mead",
                             options={"initial_simplex": simplex, "maxfev": evaluations, "xatol": 1e-3,
                                      "fatol": 1e-6 * base_misfit})


@dataclass(frozen=True)
class Fit:
    """One fitted defect: its description, where its model sits (frame, model, parameters in the
    model's own units) and the misfit of ``heights`` (the base with the defect)."""

    defect: Defect
    frame: Frame
    heights: torch.Tensor
    misfit: float

    def added_to(self, base: torch.Tensor, cell_area: float) -> torch.Tensor:
        """This defect's model applied to other heights ``base`` (m, m)."""
        return apply_model(base, self.frame, self.defect.model, self.defect.params, cell_area)


def chance_of(evidence: float, dof: int, tested: int) -> float:
    """The chance that noise alone gives ``evidence`` to a ``dof``-parameter model at any of ``tested``
    places: the chi-square tail, Bonferroni."""
    from scipy import stats
    return min(1.0, float(stats.chi2.sf(max(evidence, 0.0), dof)) * max(tested, 1))


def fit_candidate(design: torch.Tensor, base: torch.Tensor, candidate: Candidate,
                  misfit: Misfit, base_misfit: float, noise: float, cell_area: float,
                  cell_mm: float, mm_per_unit: float, evaluations: int = 60) -> Fit:
    """The best defect model at ``candidate``, added to ``base`` (its evidence against ``base``;
    confidence 1 - :func:`chance_of` at one place: the caller corrects it for the places tested).

    Args:
        design: c (m, m), scene units: the feature's frame and the height limits come from it.
        base: The heights the defect is added to (m, m): c with the defects found so far.
        misfit: ||F(d) - b||_W^2 of heights d (m, m). base_misfit: at ``base``.
        noise: Pixel noise standard deviation s (image units). cell_area: scene units^2.
        cell_mm, mm_per_unit: sample spacing and unit. evaluations: misfit evaluations per model at most.
    """
    design_np = design.double().cpu().numpy()
    frames = candidate_frames(design_np, candidate, cell_mm)
    flat = float(design_np.max()) <= 0.0 or float(design_np[candidate.rows, candidate.cols].max()) < \
        0.05 * float(design_np.max())
    ceiling = _ceiling(design_np)
    best: tuple[float, str, np.ndarray, Frame] | None = None
    for model in MODELS:
        if flat and model != "blob":
            continue
        if model == "blob":
            frame = frames[0]
            objective = _objective(base, frame, model, misfit, ceiling, cell_area)
            x0 = min(_drop_starts(design_np, candidate, cell_area), key=objective)
        else:  # in the frame whose scan fits best
            starts = [(_feature_start(misfit, base, f, model, candidate, cell_mm, cell_area), f) for f in frames]
            (x0, _), frame = min(starts, key=lambda item: item[0][1])
            objective = _objective(base, frame, model, misfit, ceiling, cell_area)
        result = _nelder_mead(objective, x0, np.array(STEPS[model]), evaluations, base_misfit)
        if best is None or result.fun < best[0]:
            best = (float(result.fun), model, result.x, frame)
    assert best is not None
    _, model, x, frame = best
    # the winner gets as many evaluations again, from where it stopped, on a smaller simplex
    return refit(design, base, frame, model, _model_params(model, x), misfit, base_misfit, noise, cell_area, cell_mm,
                 mm_per_unit, evaluations, 0.3)


def _ceiling(design: np.ndarray) -> float:
    """No print is higher than three times its design's peak: a fit's step beyond went astray."""
    return 3.0 * max(float(design.max()), 1e-12)


def _objective(base: torch.Tensor, frame: Frame, model: str, misfit: Misfit, ceiling: float,
               cell_area: float) -> Callable[[np.ndarray], float]:
    """The misfit of ``base`` with the defect ``model`` of the optimiser's parameters at ``frame``."""

    def objective(p: np.ndarray) -> float:
        heights = apply_model(base, frame, model, _model_params(model, p), cell_area)
        if float(heights.max()) > ceiling:
            return math.inf
        return misfit(heights)

    return objective


def refit(design: torch.Tensor, base: torch.Tensor, frame: Frame, model: str, start: Sequence[float],
          misfit: Misfit, base_misfit: float, noise: float, cell_area: float, cell_mm: float, mm_per_unit: float,
          evaluations: int, step_scale: float = 1.0) -> Fit:
    """The defect ``model`` at ``frame`` on top of ``base``, by Nelder-Mead from the model's parameters
    ``start`` on a simplex of ``step_scale`` times the model's steps; arguments as :func:`fit_candidate`."""
    design_np = design.double().cpu().numpy()
    objective = _objective(base, frame, model, misfit, _ceiling(design_np), cell_area)
    x0 = np.array(start, dtype=float)
    if model == "blob":  # the optimiser sees a drop's volume and radius as logarithms
        x0[2], x0[3] = math.log(x0[2]), math.log(x0[3])
    result = _nelder_mead(objective, x0, step_scale * np.array(STEPS[model]), evaluations, base_misfit)
    params = np.array(_model_params(model, result.x))
    if model == "blob":  # the volume the drop holds at its radius
        params[2] = drop_volume(float(params[2]), float(params[3]), cell_area)
    evidence = (base_misfit - float(result.fun)) / noise ** 2
    heights = apply_model(base, frame, model, tuple(float(p) for p in params), cell_area)
    change = (heights - base).double().cpu().numpy()
    defect = _described(model, params, frame, change, design_np, evidence,
                        1.0 - chance_of(evidence, len(params), 1), cell_mm, mm_per_unit)
    return Fit(defect, frame, heights, float(result.fun))


def _changed_span(change: np.ndarray, frame: Frame, t0: float, length: float, cell_mm: float
                  ) -> tuple[float, float, float]:
    """(row, col, length in mm) of a feature model's defect, its middle on the ridge: the window's
    (t0, length in samples), or where the window reaches past the feature's end (it changes nothing
    there) the span along the feature of the samples changed by at least a quarter of the largest change."""
    magnitude = np.abs(change)
    rows, cols = np.nonzero(magnitude >= 0.25 * magnitude.max())
    t = (rows - frame.row) * frame.along[0] + (cols - frame.col) * frame.along[1]
    span = float(t.max() - t.min()) + 1.0
    if length > span:
        t0, length = 0.5 * (float(t.min()) + float(t.max())), span
    row = frame.row + t0 * frame.along[0] + frame.ridge * frame.across[0]
    col = frame.col + t0 * frame.along[1] + frame.ridge * frame.across[1]
    return row, col, length * cell_mm


def _described(model: str, params: np.ndarray, frame: Frame, change: np.ndarray, design: np.ndarray,
               evidence: float, confidence: float, cell_mm: float, mm_per_unit: float) -> Defect:
    m = design.shape[0]
    half = 0.5 * (m - 1) * cell_mm
    if model == "blob":
        row, col, volume, radius = params
        kind, size, length = "excess", float(volume) * mm_per_unit ** 3, 2.355 * float(radius) * cell_mm
    else:
        t0, length_samples, amount = params
        row, col, length = _changed_span(change, frame, float(t0), float(length_samples), cell_mm)
        if model == "modulation":
            kind = "interruption" if amount >= INTERRUPTED else ("too_low" if amount > 0 else "too_high")
            size = float(amount)
        elif model == "shift":
            kind, size = "displaced", abs(float(amount)) * cell_mm
        elif amount <= -INTERRUPTED:  # narrowed to less than half its width: most of its glass is missing
            kind, size = "interruption", -float(amount)
        else:
            kind, size = ("too_wide" if amount > 0 else "too_narrow"), float(amount)
    top = np.unravel_index(int(np.argmax(np.abs(change))), change.shape)
    return Defect(kind=kind, x_mm=float(col * cell_mm - half), y_mm=float(row * cell_mm - half), length_mm=length,
                  size=size, peak_mm=float(change[top]) * mm_per_unit,
                  volume_mm3=float(change.sum()) * cell_mm ** 2 * mm_per_unit, evidence=float(evidence),
                  confidence=float(confidence), model=model, params=tuple(float(p) for p in params))


