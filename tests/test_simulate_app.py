"""sfc-simulate end to end: tiny renders in a subprocess, their files, and a clear failure."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from framework.files.height_field_io import load_height_field

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = Path(sys.executable).parent / "sfc-simulate"
TINY = ["photons=20000", "receiver.resolution=64", "height_field.resolution=32", "progress=false"]


def run_app(args: list[str], cwd: Path, console_script: bool = True) -> subprocess.CompletedProcess[str]:
    command = ([str(SCRIPT)] if console_script and SCRIPT.exists()
               else [sys.executable, "-m", "experiments.apps.simulate"])
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(command + args, cwd=cwd, env=env, capture_output=True, text=True, timeout=120)


def check_outputs(out: Path, channels: int, n: int, m: int) -> np.ndarray:
    caustic = np.load(out / "caustic.npy")
    assert caustic.shape == (channels, n, n) and caustic.dtype == np.float32
    assert np.isfinite(caustic).all() and caustic.min() >= 0.0 and caustic.max() > 0.0
    heights = np.load(out / "heights.npy")
    assert heights.shape == (m, m) and heights.dtype == np.float64
    with Image.open(out / "caustic.png") as img:
        assert img.size == (n, n) and img.mode == ("L" if channels == 1 else "RGB")
    with Image.open(out / "height_and_caustic.png") as img:
        assert img.size[0] > img.size[1] > 100
    return caustic


@pytest.mark.slow
def test_console_script_renders_the_print_lines(tmp_path: Path) -> None:
    out = tmp_path / "run"
    result = run_app(TINY + [f"hydra.run.dir={out}"], cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    caustic = check_outputs(out, channels=1, n=64, m=32)
    assert str(out) in result.stdout and "photons/s" in result.stdout
    # About 1 W * (solid angle of the 2 x 2 plate seen from z = 10) / 4 pi reaches the receiver.
    power = float(caustic.astype(np.float64).sum()) * (2.0 / 64) ** 2
    assert power == pytest.approx(4.0 / (100.0 * 4.0 * np.pi), rel=0.1)
    assert f"{power:.6g} W" in result.stdout
    assert (out / ".hydra" / "config.yaml").exists()


@pytest.mark.slow
def test_height_field_path_and_three_wavelengths(tmp_path: Path) -> None:
    heights = np.zeros((16, 16))
    heights[4:12, 4:12] = 0.01
    np.save(tmp_path / "mine.npy", heights)
    out = tmp_path / "run"
    result = run_app(TINY + [f"hydra.run.dir={out}", "height_field.path=mine.npy",
                             "wavelengths=[0.475,0.5625,0.65]", "light.position=[0,0,5]"],
                     cwd=tmp_path, console_script=False)
    assert result.returncode == 0, result.stderr
    check_outputs(out, channels=3, n=64, m=32)
    np.testing.assert_array_equal(np.load(out / "heights.npy"),
                                  load_height_field(tmp_path / "mine.npy", resolution=32))


def test_unknown_shape_fails_with_a_clear_message(tmp_path: Path) -> None:
    out = tmp_path / "run"
    result = run_app(TINY + [f"hydra.run.dir={out}", "height_field.shape=spiral"], cwd=tmp_path)
    assert result.returncode == 1
    assert result.stderr.strip().splitlines() == [
        "error: unknown shape 'spiral'; known shapes: bump, flat, gaussian, letter_a, oblique_lines, print_lines "
        "(SFC_TRACEBACK=1 shows the traceback)"]
    assert not (out / "caustic.npy").exists()


@pytest.mark.slow
def test_missing_height_file_fails_in_one_line_and_the_traceback_is_on_request(tmp_path: Path,
                                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    args = TINY + [f"hydra.run.dir={tmp_path / 'run'}", "height_field.path=missing.npy"]
    result = run_app(args, cwd=tmp_path)
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: height field file") and "missing.npy" in lines[0]
    monkeypatch.setenv("SFC_TRACEBACK", "1")
    traced = run_app(args, cwd=tmp_path)
    assert traced.returncode == 1
    assert "Traceback" in traced.stderr and "FileNotFoundError: height field file" in traced.stderr
