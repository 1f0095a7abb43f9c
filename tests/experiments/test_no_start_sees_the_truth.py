"""No start ever sees the truth: every start, data source and first fit of a stack, run on
built-in data, begins away from the print it must find, and the ground truth is read by the metrics
and the evaluation outputs alone (framework/core/truth.py).

Each run is two iterations long, so every start of ``initial=auto`` ends short of the noise level
and runs, a stack's line search included. The heights each start hands the solver are caught on
their way (the reconstruction's ``_coarse_levels``) and compared with the print by the test itself,
which knows it: for measured data (file, photo) the run has no truth to report an error with.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from framework.core.contracts.start import Start, StartRequest, StartResult
from framework.core.registry import register
from framework.core.truth import height_errors
from framework.reconstruction import reconstruction
from framework.reconstruction.reconstruction import run_reconstruction
from framework.scene.scene_config import build_heights, build_operator, build_scene
from tests.experiments.conftest import SMALL, compose_reconstruct

SCENE = ["scene=print_lines", "solver.max_iter=2", "defects.enabled=off"]
STACK = ["data=stack", "+data.common.reference_photons=200000", "+data.common.reference_resolution=128"]
NEAR_ZERO = 1e-3  # a start this close to the print (relative error of its printed heights, rel_error_d) has seen it


def _starts_seen(monkeypatch) -> dict[str, torch.Tensor]:
    """Start name -> the heights (m, m) that start handed the solver, for every start of the next runs."""
    seen: dict[str, torch.Tensor] = {}
    original = reconstruction._coarse_levels

    def spy(parts, problem, name, start, request):
        computed, metrics = original(parts, problem, name, start, request)
        seen[name] = computed.d.detach().double().clone()
        return computed, metrics

    monkeypatch.setattr(reconstruction, "_coarse_levels", spy)
    return seen


def start_leaks(metrics: dict, seen: dict[str, torch.Tensor], truth: torch.Tensor, base: float) -> list[str]:
    """What shows a start that saw the truth: a start (as the run reports it, and as the test
    measures it) within :data:`NEAR_ZERO` of the print, or a start from a design the data do not
    carry. Empty when no start saw it."""
    leaks = [f"{key} = {value:.2e}" for key, value in metrics.items()
             if key.startswith("start_") and key.endswith("_initial_rel_error_d") and value <= NEAR_ZERO]
    leaks += [f"start {name}: {errors['rel_error_d']:.2e} from the print"
              for name, d in seen.items() if (errors := height_errors(d, truth, base))["rel_error_d"] <= NEAR_ZERO]
    leaks += [f"start {name} read a design" for name in seen if name.startswith("design")]
    return leaks


def _measured(kind: str, directory: Path, cfg: dict) -> list[str]:
    """Overrides for measured data of the print: its exact caustic (the wavefront renderer) with 0.5%
    noise as a file (``file``) or as a photo of the receiver (``photo``), with its mask and volume."""
    scene = build_scene(cfg)
    operator = build_operator(cfg, scene).exact_variant(1 << 18, 7, int(cfg["receiver"]["resolution"]))
    truth = build_heights(cfg)
    image = operator.render(truth).double().numpy()
    image = image + np.random.default_rng(3).normal(size=image.shape) * 0.005 * image.std()
    np.save(directory / "mask.npy", (truth > 1e-3).numpy())
    volume = float(truth.sum()) * (2.0 * scene.substrate.half_width / (truth.shape[0] - 1)) ** 2
    if kind == "file":
        np.save(directory / "caustic.npy", image)
        return ["data=file", "data.image=caustic.npy", "data.mask=mask.npy", f"data.volume={volume}"]
    n = image.shape[-1]
    np.save(directory / "photo.npy", (image[0] / image.max() * 0.8)[::-1].astype(np.float32))
    return ["data=photo", "data.photo=photo.npy", f"data.corners=[[0,{n - 1}],[{n - 1},{n - 1}],[{n - 1},0],[0,0]]",
            "data.mask=mask.npy", f"data.volume={volume}"]


CASES = {
    "synthetic, zero": ["initial=zero"],
    "synthetic, transport": ["initial=transport"],
    "synthetic, file": ["initial=file", "initial.path=start.npy"],
    "synthetic, auto": ["initial=auto"],
    "stack, first fit none": [*STACK, "initial=auto", "data.first_fit=none"],
    "stack, first fit nearest": [*STACK, "initial=auto", "data.first_fit=nearest"],
    "stack, first fit lines": [*STACK, "initial=auto", "data.first_fit=lines"],
    "file, auto": ["initial=auto", "measured=file"],
    "photo, auto": ["initial=auto", "measured=photo"],
}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CASES))
def test_no_start_of_any_data_source_or_first_fit_sees_the_truth(case, tmp_path, monkeypatch) -> None:
    base = compose_reconstruct([*SMALL, *SCENE], tmp_path)
    truth = build_heights(base)
    overrides = [o for o in CASES[case] if not o.startswith("measured=")]
    measured = next((o.split("=")[1] for o in CASES[case] if o.startswith("measured=")), None)
    if measured:
        overrides += _measured(measured, tmp_path, base)
    np.save(tmp_path / "start.npy", 0.5 * truth.numpy()[::-1].copy())  # a file start: another shape
    seen = _starts_seen(monkeypatch)
    metrics = run_reconstruction(compose_reconstruct([*SMALL, *SCENE, *overrides], tmp_path), tmp_path / "run",
                                 tmp_path)
    assert seen, "no start ran"
    assert start_leaks(metrics, seen, truth, float(base["substrate"]["thickness"])) == []
    if measured is None:  # synthetic data report every start's initial error, and none is 0
        reported = {k: v for k, v in metrics.items() if k.startswith("start_") and k.endswith("_initial_rel_error_d")}
        assert len(reported) == len(seen) and min(reported.values()) > NEAR_ZERO, reported
    if "data.first_fit=lines" in overrides:  # the search ran, from the transport start, not the design
        assert metrics["start_transport_lines_feature_search_renders"] > 0, metrics
    assert not str(metrics["start"]).startswith("design")


class _Peek(Start):
    """A planted leak: a start that hands the solver the print itself."""

    name = "peek"
    truth: torch.Tensor

    def __call__(self, request: StartRequest) -> StartResult:
        return StartResult(self.truth.to(request.problem.operator.dtype), name=self.name, shaped=True)


@pytest.mark.slow
def test_the_sweep_catches_a_start_planted_to_read_the_truth(tmp_path, monkeypatch, own_registrations) -> None:
    base = compose_reconstruct([*SMALL, *SCENE], tmp_path)
    truth = build_heights(base)
    _Peek.truth = truth
    register("initial", "peek")(_Peek)
    seen = _starts_seen(monkeypatch)
    cfg = compose_reconstruct([*SMALL, *SCENE, "initial=auto", "~initial.candidates",
                               "+initial.candidates={zero: {}, peek: {}}", "solver.max_iter=1"], tmp_path)
    metrics = run_reconstruction(cfg, tmp_path / "run", tmp_path)
    leaks = start_leaks(metrics, seen, truth, float(base["substrate"]["thickness"]))
    assert "start_peek_initial_rel_error_d = 0.00e+00" in leaks  # as the run reports it
    assert any(leak.startswith("start peek: ") for leak in leaks)  # as the test measures it (float32 heights)
    assert not any("zero" in leak for leak in leaks)
