"""How well a reconstruction did, in plain words: every run ends with a verdict in its log,
metrics.json and MLflow.

Three questions, each answered with numbers: did the result reach the noise level (its
discrepancy against tau * delta, the discrepancy principle's goal), did it hold the known volume
(within ``VOLUME_TOLERANCE``), and which receiver pixels the fit left out and why. A run that
falls short of the noise level or of the volume gets a warning: its heights explain the data
less well than the data's noise allows, or hold another amount of glass than was deposited.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch

__all__ = ["VOLUME_TOLERANCE", "Verdict", "run_verdict", "volume_report"]

VOLUME_TOLERANCE = 0.02  # |volume / known volume - 1| within which the volume counts as held


def volume_report(d: torch.Tensor, volume: float | None, cell_area: float,
                  tolerance: float = VOLUME_TOLERANCE) -> dict[str, Any]:
    """The result's volume against the known one: ``volume_ratio`` (sum d a / V) and whether it
    holds within ``tolerance`` (``volume_held``); empty without a known volume."""
    if volume is None:
        return {}
    ratio = float(d.double().sum()) * cell_area / volume
    # + 1e-6: a result on the band's edge holds (its sum is of float32 heights)
    return {"volume_ratio": ratio, "volume_held": abs(ratio - 1.0) <= tolerance + 1e-6}


@dataclass
class Verdict:
    """The answers, as sentences and as metrics.

    Attributes:
        reached_noise_level: The discrepancy is at most tau * delta.
        discrepancy_over_delta: The relative discrepancy / delta.
        lines: One sentence per question, in order.
        warnings: The sentences of the questions answered no.
        left_out: Receiver pixels at weight 0 by reason.
    """

    reached_noise_level: bool
    discrepancy_over_delta: float
    lines: list[str]
    warnings: list[str] = field(default_factory=list)
    left_out: dict[str, int] = field(default_factory=dict)

    def metrics(self) -> dict[str, Any]:
        """For metrics.json and MLflow: the flags, the ratio, the counts and the sentences."""
        return {"reached_noise_level": self.reached_noise_level, "discrepancy_over_delta": self.discrepancy_over_delta,
                **{f"left_out_{reason}": count for reason, count in self.left_out.items()},
                "verdict": " ".join(self.lines)}


def run_verdict(rel_discrepancy: float, delta: float, tau_dis: float, returned_iteration: int, stop_reason: str,
                volume: Mapping[str, Any], weights: torch.Tensor | None, left_out: Mapping[str, int],
                never_calibrated: Sequence[str] = ()) -> Verdict:
    """The verdict of a run whose returned iterate (``returned_iteration``) has ``rel_discrepancy``
    against data of noise level ``delta`` (goal: at most ``tau_dis`` * delta); ``volume`` is
    :func:`volume_report`'s answer, ``weights`` (c, n, n) the data term's pixel weights,
    ``left_out`` the data source's counts of weight-0 pixels by reason; ``never_calibrated``:
    calibrated setup parameters that kept their configured values (a stack's shots are judged by
    its stage, framework/stack/stack_stage.py)."""
    ratio = rel_discrepancy / delta
    reached = rel_discrepancy <= tau_dis * delta
    lines, warnings = [], []
    noise = (f"discrepancy {rel_discrepancy:.4g} = {ratio:.2f} x the noise level delta {delta:g} "
             f"at iteration {returned_iteration}")
    if reached:
        lines.append(f"Reached the noise level: {noise}.")
    else:
        sentence = (f"Ended short of the noise level: {noise} (goal {tau_dis:g} x; the run stopped: {stop_reason}). "
                    "The heights explain the data less well than their noise allows: raise solver.max_iter, try "
                    "another start (initial=...), or check data.delta.")
        lines.append(sentence)
        warnings.append(sentence)
    if volume:
        held = bool(volume["volume_held"])
        sentence = (f"Volume {'held' if held else 'not held'}: {volume['volume_ratio']:.4f} x the known volume "
                    f"(tolerance {100 * VOLUME_TOLERANCE:g}%).")
        lines.append(sentence)
        if not held:
            warnings.append(sentence)
    if never_calibrated:
        sentence = (f"Not calibrated: {', '.join(never_calibrated)} kept the configured value; the fit met the noise "
                    "level before the first update of calibration.params (lower calibration.every).")
        lines.append(sentence)
        warnings.append(sentence)
    counts = dict(left_out)
    dropped = 0 if weights is None else int((weights == 0).sum())
    if dropped > sum(counts.values()):
        counts["other"] = dropped - sum(counts.values())
    counts = {reason: count for reason, count in counts.items() if count}
    if counts:
        lines.append("Left out of the fit (weight 0): " + ", ".join(
            f"{count} receiver pixels {_REASONS.get(reason, reason)}" for reason, count in counts.items()) + ".")
    else:
        lines.append("Every receiver pixel used in the fit.")
    return Verdict(reached, ratio, lines, warnings, counts)


_REASONS = {"saturated": "touching saturated photo pixels", "unlit": "outside the lit region of the flat field",
            "other": "weighted 0 by the data"}
