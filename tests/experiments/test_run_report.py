"""Honest reports: the verdict's numbers, and a lab photo (perspective, vignetting, gamma, black
level, noise, saturation) with a repeat exposure whose run states the estimated noise level, the
pixels it left out and that it ended short of the noise level."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from mlflow.tracking import MlflowClient
from PIL import Image

from experiments.paper.reproduce_lab import relative_error_after_scale
from framework.lab.photo_synthesis import synthesize_photo
from framework.reconstruction.reconstruction import run_reconstruction
from framework.reconstruction.parts import Reconstruction
from framework.scene.scene_config import build_heights, build_operator, build_scene
from framework.reconstruction.verdict import run_verdict
from tests.experiments.conftest import SMALL, compose_reconstruct

SHAPE = (360, 480)
CORNERS = [[115.0, 330.0], [372.0, 320.0], [350.0, 75.0], [132.0, 60.0]]  # 25 degrees or so off the normal
GAMMA, BLACK, NOISE, SATURATED = 2.2, 512.0, 0.03, 30


def test_the_verdict_counts_what_it_says() -> None:
    weights = torch.ones(1, 8, 8)
    weights[0, 0, :5] = 0
    ok = run_verdict(0.0505, 0.05, 1.01, 40, "morozov", {"volume_ratio": 1.01, "volume_held": True}, weights,
                     {"saturated": 3})
    assert ok.reached_noise_level and ok.discrepancy_over_delta == pytest.approx(1.01) and not ok.warnings
    assert ok.left_out == {"saturated": 3, "other": 2}
    assert "3 receiver pixels touching saturated photo pixels" in ok.lines[-1]
    short = run_verdict(0.31, 0.05, 1.01, 200, "iteration cap", {"volume_ratio": 1.155, "volume_held": False},
                        None, {})
    assert not short.reached_noise_level and short.discrepancy_over_delta == pytest.approx(6.2)
    assert len(short.warnings) == 2 and "6.20 x the noise level" in short.warnings[0]
    assert "1.1550 x the known volume" in short.warnings[1]
    assert short.lines[-1] == "Every receiver pixel used in the fit."
    kept = run_verdict(0.0505, 0.05, 1.01, 9, "morozov", {}, None, {}, never_calibrated=["screen_distance"])
    assert kept.reached_noise_level and len(kept.warnings) == 1
    assert kept.warnings[0].startswith("Not calibrated: screen_distance kept the configured value")


def _photo(image: np.ndarray, gain: float, noise: float, seed: int) -> np.ndarray:
    return synthesize_photo(image, CORNERS, SHAPE, 1.0, gain=gain, vignetting=0.3, gamma=GAMMA, black_level_dn=BLACK,
                            noise=noise, seed=seed)


@pytest.fixture(scope="module")
def lab(tmp_path_factory) -> Path:
    """Two noisy exposures, a noise-free one and the bare substrate's flat of the bump's caustic."""
    root = tmp_path_factory.mktemp("lab")
    cfg = compose_reconstruct([*SMALL, "scene=bump"], root)
    operator = build_operator(cfg, build_scene(cfg)).variant(1 << 20, 7, 128)
    image = operator.render(build_heights(cfg).to(operator.dtype)).double().numpy()
    flat = operator.render(torch.zeros(32, 32, dtype=operator.dtype)).double().numpy()
    linear = synthesize_photo(image / image.max(), CORNERS, SHAPE, 1.0, vignetting=0.3) / 65535.0
    level = float(np.sort(linear.ravel())[-SATURATED])  # the brightest pixels end near full scale
    gain = (0.98 - 2 * NOISE) ** GAMMA / (level * float(image.max()))
    for name, noise, seed in (("first", NOISE, 1), ("second", NOISE, 2), ("clean", 0.0, 0)):
        Image.fromarray(_photo(image, gain, noise, seed)).save(root / f"{name}.png")
    flat_photo = synthesize_photo(flat, CORNERS, SHAPE, 1.0, gain=0.8 / float(flat.max()), vignetting=0.3,
                                  gamma=GAMMA, black_level_dn=BLACK, noise=NOISE / 8, seed=3, extend_edges=True)
    Image.fromarray(flat_photo).save(root / "flat.png")
    return root


def _photo_args(photo: str, *extra: str) -> list[str]:
    return ["scene=bump", "data=photo", f"data.photo={photo}", "data.flat=flat.png", "data.response=gamma",
            f"data.gamma={GAMMA}", f"data.black_level={BLACK}", f"data.corners={json.dumps(CORNERS)}".replace(" ", ""),
            "~solver.post_steps.volume_v1", "~solver.post_steps.volume_hold", *extra]


def _loaded(lab: Path, args: list[str]):
    parts = Reconstruction.from_config(compose_reconstruct([*SMALL, *args], lab), lab)
    return parts.data_source.load(parts.data_request(lab))


@pytest.mark.slow
def test_the_noise_level_estimated_from_two_exposures_is_the_datas(lab) -> None:
    data = _loaded(lab, _photo_args("first.png", "data.repeat=second.png", "data.delta=auto"))
    clean = _loaded(lab, _photo_args("clean.png"))
    weights = data.weights.numpy() * clean.weights.numpy()
    true_delta = relative_error_after_scale(data.target.numpy(), clean.target.numpy(), weights)
    assert 0.005 < true_delta < 0.2  # a noise level the test can tell apart
    assert data.delta == pytest.approx(true_delta, rel=0.1)
    assert data.left_out["saturated"] > 0


def test_a_short_run_on_a_lab_photo_says_how_well_it_did(lab, tmp_path, capsys) -> None:
    cfg = compose_reconstruct([*SMALL, *_photo_args("first.png", "data.repeat=second.png", "data.delta=auto"),
                               "solver.max_iter=2"], tmp_path)
    metrics = run_reconstruction(cfg, tmp_path / "run", lab)
    imported = json.loads((tmp_path / "run" / "photo_import.json").read_text())
    assert metrics["delta"] == imported["delta"] and imported["delta_estimated"]
    assert not metrics["reached_noise_level"]
    assert metrics["discrepancy_over_delta"] == pytest.approx(metrics["rel_discrepancy"] / metrics["delta"])
    assert metrics["verdict"].startswith("Ended short of the noise level")
    assert metrics["left_out_saturated"] == imported["left_out"]["saturated"] > 0
    assert not any(key.startswith("deviation_") for key in metrics)  # no design was given
    err = capsys.readouterr().err
    assert "warning: Ended short of the noise level" in err
    saved = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert saved["verdict"] == metrics["verdict"]
    client = MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'mlruns' / 'mlflow.db'}")
    (run,) = client.search_runs([client.get_experiment_by_name("shape-from-caustics").experiment_id])
    assert run.data.tags["verdict"] == metrics["verdict"] and run.data.metrics["reached_noise_level"] == 0.0
    assert run.inputs.dataset_inputs[0].dataset.name == "first.png"  # the data source names its file
