"""The mesh scenes' renders: logged to MLflow with their intrinsic noise, rebuilt into the figure."""

from __future__ import annotations

import numpy as np
import pytest

from experiments.paper.reproduce_fig4 import main, to_rgb


@pytest.mark.slow
def test_renders_are_logged_and_the_noise_falls_with_the_photon_count(tmp_path):
    main(["--store", str(tmp_path / "mlruns"), "--out", str(tmp_path / "out"), "--high", "80000", "--low", "5000",
          "--overrides", "receiver.resolution=32", "height_field.resolution=16"])
    rows = [line.split("|") for line in (tmp_path / "out" / "fig4.md").read_text().splitlines()[2:]]
    noise = {(r[1].strip(), int(r[2].replace(",", ""))): float(r[3]) for r in rows}
    assert set(noise) == {(s, p) for s in ("two_lenses", "prism_lens_array") for p in (80000, 5000)}
    for scene in ("two_lenses", "prism_lens_array"):
        # Photon noise falls like 1/sqrt(photons): 16x the photons, about a quarter of the noise
        # (measured 0.25 and 0.13: the lenslets' sharp foci are undersampled by 5,000 photons).
        assert 0.1 < noise[(scene, 80000)] / noise[(scene, 5000)] < 0.4, noise
    assert (tmp_path / "out" / "fig4.png").stat().st_size > 10_000


def test_three_wavelengths_map_to_blue_green_red():
    image = np.zeros((3, 4, 4))
    image[0] = 1.0  # the shortest wavelength
    rgb = to_rgb(image)
    assert rgb.shape == (4, 4, 3) and rgb[..., 2].min() == 1.0 and rgb[..., :2].max() == 0.0
