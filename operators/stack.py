"""Several setups, one print: the same heights rendered into N setups (screen distances, light
positions, camera gains), the images stacked along the channel axis.

With the operators F_1 .. F_N of the N shots (each (c, n, n)) and per-shot misfit weights w_i,

    S(d) = [sqrt(w_1) F_1(d); ...; sqrt(w_N) F_N(d)]      (N c, n, n),

so that the squared misfit of the stack against the stacked data [sqrt(w_i) b_i] is the weighted
sum sum_i w_i ||F_i(d) - b_i||^2 (the weights W a linear map, operators/linear/shot_weights.py) and
its gradient the weighted sum of the shots' gradients:
S'(d)^* [g_1; ...; g_N] = sum_i sqrt(w_i) F_i'(d)^* g_i (docs/method.md, "Several photos").
A stack of one with weight 1 renders and differentiates exactly as its one operator does. Shots
whose photons meet the print alike (the height-field operator with the same light: screens at
several distances) search the print for the photons' hits once per set of heights; the other
shots replay them.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import AbstractContextManager
from typing import Any

import torch

from operators.linear.shot_weights import ShotWeights
from operators.image_operator import ImageOperator

__all__ = ["StackOperator"]


class StackOperator(ImageOperator):
    """The shots' operators rendering the same heights; images stacked along the channel axis.

    Args:
        shots: The operator of every shot (the same dtype, photons and image shape (c, n, n)).
        weights: w_i >= 0, the weight of shot i's squared misfit (None: 1 each).
        share_hits: Let shots whose photons meet the print alike share their hit search.
    """

    def __init__(self, shots: Sequence[Any], weights: Sequence[float] | None = None, share_hits: bool = True) -> None:
        shots = list(shots)
        if not shots:
            raise ValueError("a stack needs at least one shot (data.shots=[...])")
        first = shots[0]
        for i, shot in enumerate(shots[1:], start=1):
            for key in ("output_shape", "dtype", "photons"):
                if getattr(shot, key) != getattr(first, key):
                    raise ValueError(f"shot {i} has {key} {getattr(shot, key)} but shot 0 has {getattr(first, key)}; "
                                     "the shots of a stack share the receiver's pixels, the dtype and the photons")
        self.shots = shots
        self.reweight([1.0] * len(shots) if weights is None else weights)
        self.configured_weights = list(self.weights)  # as built, before any reweighting by the data
        if share_hits:
            self._share_hits()

    def reweight(self, weights: Sequence[float]) -> None:
        """Set the shots' misfit weights w_i > 0 (one per shot)."""
        weights = [float(w) for w in weights]
        if len(weights) != len(self.shots):
            raise ValueError(f"stack weights {weights} must be one positive number per shot ({len(self.shots)})")
        self.weighting = ShotWeights(weights, int(self.shots[0].output_shape[0]))

    @property
    def weights(self) -> list[float]:
        """w_i, the shots' misfit weights."""
        return self.weighting.weights

    @property
    def scales(self) -> list[float]:
        """sqrt(w_i), the shots' image scales."""
        return self.weighting.scales

    def _share_hits(self) -> None:
        """Shots whose photons meet the print alike (the same light and photon pattern; only the
        screen differs) share one hit cache: the hits one shot's render finds at some heights, the
        next shot's render of the same heights replays (operators/heightfield/trace_native.py)."""
        first: dict[Any, Any] = {}
        for shot in self.shots:
            key = shot.hit_key
            if key is None:
                continue
            if key in first:
                shot.share_hits(first[key])
            else:
                first[key] = shot

    # -- the operator contract -------------------------------------------------------------------
    @property
    def dtype(self) -> torch.dtype:  # type: ignore[override]
        return self.shots[0].dtype

    @property
    def photons(self) -> int:
        """Photons traced per shot and evaluation (a pass traces ``photons`` x :attr:`shot_count`)."""
        return int(self.shots[0].photons)

    @property
    def shot_count(self) -> int:
        """N, the number of shots."""
        return len(self.shots)

    @property
    def pixel_area(self) -> float:
        return float(self.shots[0].pixel_area)

    @property
    def channels_per_shot(self) -> int:
        """c, the channels of one shot's image."""
        return int(self.shots[0].output_shape[0])

    @property
    def output_shape(self) -> tuple[int, int, int]:
        c, n, _ = self.shots[0].output_shape
        return (len(self.shots) * c, n, n)

    @property
    def conserves_energy(self) -> bool:  # type: ignore[override]
        return all(bool(shot.conserves_energy) for shot in self.shots)

    @property
    def revision(self) -> int:  # type: ignore[override]
        """Changes whenever a shot's setup changes (joint calibration)."""
        return sum(int(shot.revision) for shot in self.shots)

    def blocks(self, image: torch.Tensor) -> list[torch.Tensor]:
        """The shots' parts (c, n, n) of a stacked image (N c, n, n)."""
        if tuple(image.shape) != self.output_shape:
            raise ValueError(f"a stacked image has shape {self.output_shape}, got {tuple(image.shape)}")
        return self.weighting.blocks(image)

    def stack(self, images: Sequence[torch.Tensor]) -> torch.Tensor:
        """The shots' images (c, n, n) each, weighted and stacked (N c, n, n)."""
        return self.weighting.weighted(images)

    def render(self, heights: torch.Tensor, progress: bool = False) -> torch.Tensor:
        """[sqrt(w_i) F_i(d)] (N c, n, n)."""
        return self.stack([shot.render(heights, progress=progress) for shot in self.shots])

    @property
    def has_jvp(self) -> bool:  # type: ignore[override]
        """Whether every shot gives its Jacobian-vector product."""
        return all(shot.has_jvp for shot in self.shots)

    def jvp(self, heights: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
        """[sqrt(w_i) F_i'(d) v] (N c, n, n)."""
        return self.stack([shot.jvp(heights, direction) for shot in self.shots])

    def vjp(self, heights: torch.Tensor, grad_image: torch.Tensor) -> torch.Tensor:
        """sum_i sqrt(w_i) F_i'(d)^* g_i (m, m) for the stacked image gradient [g_i]."""
        total = None
        for shot, block in zip(self.shots, self.blocks(self.weighting.adjoint(grad_image))):
            part = shot.vjp(heights, block)
            total = part if total is None else total + part
        return total

    def loss_and_grad(self, heights: torch.Tensor, target: torch.Tensor, image: torch.Tensor | None = None
                      ) -> tuple[float, torch.Tensor, torch.Tensor]:
        """sum_i w_i 1/2 ||F_i(d) - b_i||^2 and its gradient, each shot by its own operator
        (``target`` and ``image`` stacked as :meth:`render` stacks them)."""
        images = [None] * len(self.shots) if image is None else [
            block / scale for block, scale in zip(self.blocks(image), self.scales)]
        loss, total, rendered = 0.0, None, []
        for shot, scale, block, known in zip(self.shots, self.scales, self.blocks(target), images):
            value, grad, shot_image = shot.loss_and_grad(heights, block / scale, image=known)
            loss += scale * scale * value
            grad = grad * (scale * scale)
            total = grad if total is None else total + grad
            rendered.append(shot_image)
        return loss, total, self.stack(rendered)

    def variant(self, photons: int, seed: int, resolution: int) -> StackOperator:
        """The same shots and weights, each with another sampling."""
        return StackOperator([shot.variant(photons, seed, resolution) for shot in self.shots], self.weights)

    def warm_up(self) -> AbstractContextManager[Any]:
        """The first shot's warm-up (the shots are built by the same plugin)."""
        return self.shots[0].warm_up()
