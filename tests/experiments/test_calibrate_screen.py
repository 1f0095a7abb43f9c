"""sfc-calibrate-screen (experiments/apps/calibrate_screen.py): the screen's blur found by its profile on
honest data (the exact reference, blurred by the true width), the result files, reruns and verdicts."""

from __future__ import annotations

import json

import pytest

import experiments.apps.calibrate_screen as calibrate_screen
from experiments.apps.calibrate_screen import calibrate, main, verdict

PIXEL = 2.0 / 64  # the 64-pixel receiver's pixel, scene units
TRUE_PX = 1.5
SMALL_BUMP = ["scene=bump", "photons=60000", "receiver.resolution=64", "height_field.resolution=32",
              "data.reference_photons=200000", "data.reference_resolution=128", "checkpoint_every=10",
              "screen.psf=gaussian", f"screen.sigma={TRUE_PX * PIXEL}", "data.delta=0.005",
              # A sample with blackened edges: with clear walls the sharp band of wall light at the
              # receiver's edge makes 20-iteration fits at narrow widths lag, and the profile
              # prefers 2.5 px for the true 1.5 px (docs/method.md, "The screen's blur from the photo").
              "substrate.walls=absorbing"]


@pytest.mark.slow
def test_the_blur_of_a_low_noise_caustic_is_found_and_a_rerun_reuses_the_fits(tmp_path, monkeypatch) -> None:
    overrides = [*SMALL_BUMP, f"tracking.store_dir={tmp_path / 'mlruns'}"]
    result = calibrate(overrides, tmp_path / "work", (0.7, 1.4, 2.8), iterations=20)
    assert result["identified"] and result["sigma_px"] == pytest.approx(TRUE_PX, rel=0.1)
    assert result["sigma"] == pytest.approx(result["sigma_px"] * PIXEL)
    assert result["sigma_mm"] == pytest.approx(result["sigma"] * 25.0)
    misfits = {p["sigma_px"]: p["rel_discrepancy"] for p in result["profile"]}
    assert misfits[1.4] < misfits[0.7] and misfits[1.4] < misfits[2.8]  # the minimum lies inside the grid
    assert result["best_misfit_over_delta"] < 1.2
    saved = json.loads((tmp_path / "work" / "screen_calibration.json").read_text())
    assert saved == result and (tmp_path / "work" / "screen_profile.png").stat().st_size > 0
    assert result["verdict"].endswith(f"screen.psf=gaussian screen.sigma={result['sigma']:.6g}")

    def refuse(*_args, **_kwargs):
        raise AssertionError("a finished fit ran again")

    monkeypatch.setattr(calibrate_screen, "run_reconstruction", refuse)
    assert calibrate(overrides, tmp_path / "work", (0.7, 1.4, 2.8), iterations=20) == result
    with pytest.raises(ValueError, match="holds fits of other settings"):  # never mixed with other fits
        calibrate(overrides, tmp_path / "work", (0.7, 1.4, 2.8), iterations=30)


def _result(**changes) -> dict:
    base = {"sigma_px": 1.2, "sigma": 0.01875, "sigma_mm": 0.46875, "identified": True, "rise_at_factor_2": 0.4,
            "at_bound": "", "best_misfit_over_delta": 1.05}
    return {**base, **changes}


def test_the_verdict_gives_the_override_or_says_why_the_width_is_not_told() -> None:
    assert verdict(_result()).endswith("reconstruct with screen.psf=gaussian screen.sigma=0.01875")
    assert "1.200 px" in verdict(_result()) and "rises 40%" in verdict(_result())
    flat = verdict(_result(identified=False, rise_at_factor_2=0.01))
    assert flat.startswith("Screen blur not told") and "absorb" in flat
    bound = verdict(_result(identified=False, at_bound="lower", sigma_px=0.175))
    assert bound.startswith("Screen blur not told") and "lower bound (0.175 px)" in bound
    far = verdict(_result(identified=False, best_misfit_over_delta=3.4))
    assert "3.40 x the noise level" in far and "raise --iterations" in far


def test_bad_arguments_end_in_one_line(tmp_path, capsys) -> None:
    with pytest.raises(SystemExit, match=r"--iterations=0 must be an integer >= 1"):
        main(["--iterations", "0", "--work", str(tmp_path), "scene=bump"])
    with pytest.raises(SystemExit, match=r"width grid \[0.5, 1.0\] must hold >= 3 widths"):
        main(["--widths", "0.5", "1.0", "--work", str(tmp_path), "scene=bump"])
