"""``data=stack``: several caustics of one print, each in its own setup, fitted together.

Every shot is a measurement of its own: a synthetic render, a file or a photo (the ``source`` and
that data plugin's keys: image, photo, corners, flat, delta, ...), with the screen's distance
below the substrate (``screen_distance``, or ``offset`` from the configured ``receiver.z``), the
light (``light``, or ``light_offset`` from the configured ``light.position``), the receiver's
half width and the camera gain the model starts from, and the weight of its misfit. The forward
operator renders the same heights into every shot's setup (operators/stack.py) and the data
term is the weighted sum of the shots' misfits; Morozov's rule reads the stacked discrepancy
against the stacked noise level (docs/method.md, "Several photos").

A shot's offsets are what a translation stage or a lamp rail measures; the configured distance
and light may be off, and joint calibration (framework/lab/calibration.py) then fits them
with the heights, the offsets between the shots held fixed.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import torch

from framework.core.contracts.data_source import DataRequest, PrintFacts, ShotStack
from framework.core.data import ReconstructionData, weighted_norm_sq
from framework.core.plugin_config import build_plugin
from framework.core.registry import available
from framework.core.shots import SETUP_KEYS, ShotSetup, shot_setup
from framework.data.sources import FileData
from framework.files.image_io import load_caustic_image, resolve_path
from operators.scene import Scene
from operators.values import checked_whole

__all__ = ["StackData", "noise_weights", "stacked_data"]

SHOT_SEED_STRIDE = 100_000  # shot i's reference renders and noise draw from seed + i * stride

def stacked_data(shots: Sequence[ReconstructionData], weights: Sequence[float], start_shot: int,
                 first_fit_shot: int | None = None, line_search: bool = False) -> ReconstructionData:
    """The data of a stack from its shots' data: targets scaled by sqrt(w_i) and stacked along the
    channel axis, pixel weights stacked, the noise level
    delta = sqrt(sum w_i delta_i^2 ||b_i||^2 / sum w_i ||b_i||^2), the print's mask and volume of
    shot 0, the truth and the design of the first shot that has one, every shot's source."""
    scales = [math.sqrt(w) for w in weights]
    norms = [w * weighted_norm_sq(s.target, s.weights) for s, w in zip(shots, weights)]
    delta = math.sqrt(sum(n * s.delta ** 2 for n, s in zip(norms, shots)) / sum(norms))
    pixel_weights = None
    if any(s.weights is not None for s in shots):
        pixel_weights = torch.cat([torch.ones_like(s.target) if s.weights is None else s.weights.to(s.target)
                                   for s in shots])
    intrinsic = None
    if all(s.intrinsic_noise is not None for s in shots):
        intrinsic = math.sqrt(sum(n * s.intrinsic_noise ** 2 for n, s in zip(norms, shots)) / sum(norms))
    left_out: dict[str, int] = {}
    for s in shots:
        for reason, count in s.left_out.items():
            left_out[reason] = left_out.get(reason, 0) + count
    sources = [s.source for s in shots if s.source]
    truth = next((s.ground_truth for s in shots if s.ground_truth is not None), None)
    design = next((s.design for s in shots if s.design is not None), None)
    first = shots[0]
    return ReconstructionData(
        target=torch.cat([s.target * k for s, k in zip(shots, scales)]), mask=first.mask, volume=first.volume,
        delta=delta, weights=pixel_weights, ground_truth=truth, intrinsic_noise=intrinsic, design=design,
        left_out=left_out, source="; ".join(sources) if sources else None, shots=tuple(shots), start_shot=start_shot,
        first_fit_shot=first_fit_shot, line_search=line_search)


def noise_weights(shots: Sequence[ReconstructionData], weights: Sequence[float],
                  distances: Sequence[float]) -> list[float]:
    """``weights`` times 1 / (delta_i^2 ||b_i||_W^2), scaled so that the nearest screen's shot keeps
    its weight: each shot's misfit in units of its own noise (``data.weighting: noise``)."""
    inverse_noise = [1.0 / (s.delta ** 2 * weighted_norm_sq(s.target, s.weights)) for s in shots]
    nearest = min(range(len(distances)), key=lambda i: distances[i])
    return [w * r / inverse_noise[nearest] for w, r in zip(weights, inverse_noise)]


def _named(index: int, step: Any, request: DataRequest) -> Any:
    """``step(request)`` of shot ``index``'s source, its errors prefixed with the shot."""
    try:
        return step(request)
    except FileNotFoundError as error:
        raise FileNotFoundError(f"data.shots[{index}]: {error}") from None
    except ValueError as error:
        raise ValueError(f"data.shots[{index}]: {error}") from None


class StackData(ShotStack):
    """Several measurements of one print (``data=stack``), module docstring.

    Args:
        shots: One mapping per shot: ``source`` (synthetic | file | photo, default synthetic), the
            setup keys (``screen_distance`` or ``offset``, ``light`` or ``light_offset``,
            ``receiver_half_width``, ``gain``, ``weight``) and that source's own keys.
        common: Keys given to every shot that does not set them (e.g. ``{delta: 0.05}``).
        start_shot: The shot a start reads (the transport start inverts one caustic): its index, or
            ``farthest`` (the shot with the farthest screen, whose caustic is the strongest).
        weighting: ``equal``: each shot's misfit counts with its ``weight`` (the maximum-likelihood
            weighting for shots of equal noise); ``distance``: times (s_near / s_i)^2, s_i the
            shot's screen distance and s_near the nearest one's. A screen k times farther
            displaces the light k times more for the same slope error, so its misfit weighs about
            k^2 more in the gradient; ``distance`` evens that out (docs/method.md, "Several photos");
            ``noise``: times 1 / (delta_i^2 ||b_i||^2), relative to the nearest shot's, the
            maximum-likelihood weighting for shots whose noise is a share delta_i of their norm:
            each shot's relative misfit counts alike, however bright or peaked its caustic.
        first_fit: ``nearest``: a run from flat glass fits the nearest shot alone first
            (framework/stack/first_fit.py); ``lines``: the same, and when every start ends short
            of the noise level, one run more: the first start computed on the nearest shot, that
            shot fitted alone, every line of its fit searched across basins by the misfit of every
            shot (framework/stack/line_search.py), then the stack; ``none``: the whole stack
            from the start.
    """

    FIRST_FITS = ("nearest", "lines", "none")

    WEIGHTINGS = ("equal", "distance", "noise")

    @staticmethod
    def example_settings() -> dict[str, Any]:
        """Settings of the contract checks (framework/core/contracts/checks.py): two synthetic shots,
        the configured screen and one 0.1 farther, with small reference renders."""
        return {"shots": [{"offset": 0.0}, {"offset": 0.1}],
                "common": {"reference_photons": 1 << 18, "reference_resolution": 64}}

    def __init__(self, shots: Sequence[Mapping[str, Any]] | None = None, common: Mapping[str, Any] | None = None,
                 start_shot: int | str = "farthest", weighting: str = "equal", first_fit: str = "lines") -> None:
        if weighting not in self.WEIGHTINGS:
            raise ValueError(f"data.weighting={weighting!r}; use {', '.join(self.WEIGHTINGS)}")
        if first_fit not in self.FIRST_FITS:
            raise ValueError(f"data.first_fit={first_fit!r}; use one of {', '.join(self.FIRST_FITS)}")
        self.weighting, self.first_fit = weighting, first_fit
        if not isinstance(shots, (list, tuple)) or not shots:
            raise ValueError(f"data.shots={shots!r}: a stack needs a list of one or more shots, e.g. "
                             "data.shots='[{screen_distance: 0.05}, {screen_distance: 0.2}]'")
        if common is not None and not isinstance(common, Mapping):
            raise ValueError(f"data.common={common!r} must be a mapping of keys every shot gets, e.g. {{delta: 0.05}}")
        if start_shot != "farthest":
            start_shot = checked_whole(start_shot, "data.start_shot", 0, len(shots) - 1,
                                       must=f"must be 'farthest' or a shot index in [0, {len(shots)})")
        self.specs: list[dict[str, Any]] = []
        self.sources: list[Any] = []
        for i, spec in enumerate(shots):
            where = f"data.shots[{i}]"
            if not isinstance(spec, Mapping):
                raise ValueError(f"{where}={spec!r} must be a mapping (source, screen_distance or offset, ...)")
            spec = {**dict(common or {}), **dict(spec)}
            name = spec.get("source", "synthetic")
            if name == "stack" or name not in available("data"):
                raise ValueError(f"{where}.source={name!r}; use one of "
                                 f"{', '.join(n for n in available('data') if n != 'stack')}")
            self.specs.append(spec)
            self.sources.append(build_plugin("data", name, {k: v for k, v in spec.items() if k not in SETUP_KEYS},
                                             where))
        self.start_shot = start_shot

    def setups(self, base: Scene, mm: float) -> list[ShotSetup]:
        """Every shot's setup against the configured scene ``base`` (``mm`` mm per scene unit)."""
        setups = [shot_setup(spec, f"data.shots[{i}]", base, mm) for i, spec in enumerate(self.specs)]
        distances = [-setup.scene(base, f"data.shots[{i}]").receiver.z for i, setup in enumerate(setups)]
        if self.weighting == "distance":
            setups = [dataclasses.replace(setup, weight=setup.weight * (min(distances) / z) ** 2)
                      for setup, z in zip(setups, distances)]
        return setups

    def _requests(self, request: DataRequest) -> list[DataRequest]:
        shots = request.operator.shots
        if len(shots) != len(self.sources):
            raise ValueError(
                "data=stack needs the stacked operator of its shots (framework/reconstruction/reconstruction.py "
                "builds it from data.shots)"
            )
        return [dataclasses.replace(request, operator=shot, seed=request.seed + i * SHOT_SEED_STRIDE,
                                    output_dir=None if request.output_dir is None or len(shots) == 1
                                    else request.output_dir / f"shot{i}")
                for i, shot in enumerate(shots)]

    def check(self, request: DataRequest) -> PrintFacts:
        """Every shot's files and print facts checked; the shots must agree on the print."""
        facts = [_named(i, source.check, shot) for i, (source, shot) in enumerate(zip(self.sources,
                                                                                    self._requests(request)))]
        for i, fact in enumerate(facts[1:], start=1):
            if tuple(fact.mask.shape) != tuple(facts[0].mask.shape) or not torch.equal(fact.mask, facts[0].mask):
                raise ValueError(f"data.shots[{i}] has another printed-area mask than shot 0; one print has one mask "
                                 "(give the same mask, e.g. data.common.mask=...)")
            if fact.volume != facts[0].volume:
                raise ValueError(f"data.shots[{i}].volume={fact.volume} but shot 0 says {facts[0].volume}; one print "
                                 "has one volume (give it once, data.common.volume=...)")
        self._check_image_sizes(request)
        return facts[0]

    def _check_image_sizes(self, request: DataRequest) -> None:
        """Image files (``source: file``) cover the receiver as they are: files of different sizes
        would be different framings, which only a photo's corners can map."""
        sizes = [(i, tuple(load_caustic_image(resolve_path(s.image, request.base_dir)).shape[-2:]))
                 for i, s in enumerate(self.sources) if isinstance(s, FileData)]
        for i, size in sizes[1:]:
            if size != sizes[0][1]:
                raise ValueError(
                    f"data.shots[{i}].image is {size[0]}x{size[1]} px but data.shots[{sizes[0][0]}].image is "
                    f"{sizes[0][1][0]}x{sizes[0][1][1]}; images of one stack must frame the receiver "
                    "alike: resample them, or use source: photo with each photo's corners"
                )

    def load(self, request: DataRequest) -> ReconstructionData:
        """Every shot's data from its own source in its own setup, stacked (:func:`stacked_data`)."""
        requests = self._requests(request)
        shots = [_named(i, source.load, shot) for i, (source, shot) in enumerate(zip(self.sources, requests))]
        distances = [-r.operator.scene.receiver.z for r in requests]
        if self.weighting == "noise":
            request.operator.reweight(noise_weights(shots, request.operator.configured_weights, distances))
        weights = request.operator.weights
        start = self.start_shot
        if start == "farthest":
            start = max(range(len(distances)), key=lambda i: distances[i])
        nearest = min(range(len(distances)), key=lambda i: distances[i])
        first = nearest if self.first_fit != "none" and len(shots) > 1 else None
        return stacked_data(
            shots, weights, int(start), first, line_search=first is not None and self.first_fit == "lines"
        )
