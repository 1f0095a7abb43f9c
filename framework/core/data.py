"""Data for reconstructions: synthetic (ground truth -> noisy reference) or measured (files).

Synthetic data (docs/method.md, "Synthetic data and noise"): the ground truth is rendered twice
with independent seeds (and usually more photons or pixels than the reconstruction uses), both
renders are resampled to the reconstruction's receiver, their mean is the clean reference b and
delta_sim = ||b1 - b2|| / (2 ||b||) estimates its intrinsic noise (the noise of a mean of two
independent renders). Gaussian noise of norm (delta - delta_sim) ||b|| is then added, so that
||b^delta - b_exact|| <= delta ||b|| by the triangle inequality; delta < delta_sim is refused.
Noise is added after resampling, so delta is the noise level of the data the solver sees.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from collections.abc import Callable

import torch
import torch.nn.functional as F

from framework.core.masks import mask_from_height_field
from framework.core.truth import GroundTruth
from operators.values import checked_number


@dataclass
class ReconstructionData:
    """What a reconstruction needs besides the operator.

    target: b^delta (c, n, n); mask: printed area (m, m) bool; volume: deposited volume in scene
    units^3 (None if unknown); delta: relative noise level for the discrepancy principle;
    weights (c, n, n) in [0, 1]: pixels the fit uses (None: all; a photo's saturated pixels get 0);
    ground_truth (sealed, framework/core/truth.py) and intrinsic_noise: synthetic data only, the
    truth taken off before the data reach a problem (:meth:`without_truth`); left_out:
    receiver pixels at weight 0 by reason (e.g. ``saturated``, ``unlit``), for the run's report;
    source: the file the measured data were read from (the run logs it as the dataset's source);
    design: the print's design (m, m), scene units, when one was given (None: no design, or synthetic
    data of a print equal to its configuration, whose ground truth is then no design but the answer);
    shots: a stack's data shot by shot (framework/stack/stack_data.py; empty for one image), whose
    target above stacks theirs along the channel axis; start_shot: the shot a start reads;
    first_fit_shot: the shot a run from flat glass fits alone first (None: none); line_search:
    when every start ends short of the noise level, one more run fits that shot alone and
    searches its lines across basins before the stack (framework/stack/line_search.py).
    """

    target: torch.Tensor
    mask: torch.Tensor
    volume: float | None
    delta: float
    weights: torch.Tensor | None = None
    ground_truth: GroundTruth | None = None
    intrinsic_noise: float | None = None
    left_out: dict[str, int] = field(default_factory=dict)
    source: str | None = None
    design: torch.Tensor | None = None
    shots: tuple[ReconstructionData, ...] = ()
    start_shot: int = 0
    first_fit_shot: int | None = None
    line_search: bool = False

    def without_truth(self) -> ReconstructionData:
        """These data, and every shot's, without the ground truth: what a problem carries."""
        return replace(self, ground_truth=None, shots=tuple(shot.without_truth() for shot in self.shots))


def weighted_norm_sq(image: torch.Tensor, weights: torch.Tensor | None) -> float:
    """sum w image^2 over an image (c, n, n) in float64, with per-pixel weights w (None: 1)."""
    squares = image.double() ** 2
    return float((squares if weights is None else squares * weights.double()).sum())


def resample_image(image: torch.Tensor, resolution: int) -> torch.Tensor:
    """Resample (c, N, N) irradiance to (c, n, n): area averaging down, bilinear up (keeps units)."""
    if image.shape[-1] == resolution:
        return image
    batch = image.unsqueeze(0)
    if image.shape[-1] > resolution:
        out = F.adaptive_avg_pool2d(batch, resolution)
    else:
        out = F.interpolate(batch, size=(resolution, resolution), mode="bilinear", align_corners=False)
    return out[0]


def validate_delta(delta: float, key: str = "data.delta") -> float:
    """The relative noise level delta (config key ``key``) as a float; refused unless it lies in (0, 1)."""
    return checked_number(delta, key, above=0.0, below=1.0, example="0.05")


def synthetic_data(ground_truth: torch.Tensor, render_a: Callable[[torch.Tensor], torch.Tensor],
                   render_b: Callable[[torch.Tensor], torch.Tensor] | None, resolution: int, delta: float,
                   seed: int, pixel_area: float, mask_threshold: float = 1e-3,
                   mask_dilation: float = 0.05, design: torch.Tensor | None = None) -> ReconstructionData:
    """Noisy reference caustic of ``ground_truth`` (m, m) from two independent renders.

    With a ``design`` (m, m) the printed area comes from it (what is known of a measured print) and
    the data carry it; else from the ground truth.

    render_a / render_b render (c, N, N) images with independent photon seeds (render_b None: the
    method of render_a carries no render noise, and one render is the clean image); ``seed`` draws
    the added Gaussian noise; ``pixel_area`` (scene units^2 per height sample) gives the volume.
    """
    delta = validate_delta(delta)
    first = resample_image(render_a(ground_truth).double(), resolution)
    second = first if render_b is None else resample_image(render_b(ground_truth).double(), resolution)
    clean = 0.5 * (first + second)
    norm = float(torch.linalg.vector_norm(clean))
    intrinsic = float(torch.linalg.vector_norm(first - second)) / (2.0 * norm)
    if delta < intrinsic:
        raise ValueError(f"data.delta={delta} is below the reference's intrinsic noise {intrinsic:.4f}; raise "
                         "data.delta or render the reference with more photons (data.reference_photons)")
    noise = torch.randn(clean.shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    noise *= (delta - intrinsic) * norm / float(torch.linalg.vector_norm(noise))
    truth = ground_truth.double()
    return ReconstructionData(
        target=clean + noise, mask=mask_from_height_field(truth if design is None else design.double(),
                                                          mask_threshold, mask_dilation),
        volume=float(truth.sum()) * pixel_area, delta=delta, ground_truth=GroundTruth(truth),
        intrinsic_noise=intrinsic, design=None if design is None else design.double())


def measured_data(image: torch.Tensor, resolution: int, delta: float, mask: torch.Tensor,
                  volume: float | None, flat_render_total: float | None, source: str | None = None
                  ) -> ReconstructionData:
    """Reconstruction data from a measured caustic (c, N, N).

    With ``flat_render_total`` the image is scaled so that its total equals that of the simulated
    caustic of the bare substrate: photo brightness is arbitrary, but the power reaching the
    receiver barely depends on the printed heights (energy conservation).
    """
    delta = validate_delta(delta)
    target = resample_image(image.double(), resolution)
    if float(target.sum()) <= 0.0:
        raise ValueError("the caustic image is all zero (or negative); check the file")
    if flat_render_total is not None:
        target = target * (flat_render_total / float(target.sum()))
    return ReconstructionData(target=target, mask=mask, volume=volume, delta=delta, source=source)
