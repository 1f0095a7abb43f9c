"""Bad inputs raise ValueError with the offending value in the message."""

from __future__ import annotations

import pytest
import torch

from regularizers import (
    HeightBounds,
    PixelL1,
    PixelL1Bounds,
    RegularizerContext,
    VolumeHeuristic,
    VolumeSlabL1Bounds,
    WaveletTransform,
)


def test_lower_bound_above_upper_bound() -> None:
    with pytest.raises(ValueError, match=r"p1=0\.5.*p2=0\.3"):
        HeightBounds(p1=0.5, p2=0.3)
    with pytest.raises(ValueError, match=r"p1=0\.5"):
        PixelL1Bounds(p1=0.5, p2=0.3)


def test_wrong_mask_shape() -> None:
    reg = HeightBounds()
    reg.setup(RegularizerContext(mask=torch.ones(64, 64, dtype=torch.bool)))
    with pytest.raises(ValueError, match=r"\(64, 64\).*\(128, 128\)"):
        reg.prox(torch.zeros(128, 128), 0.1)


def test_non_bool_mask() -> None:
    with pytest.raises(ValueError, match="torch.float32"):
        RegularizerContext(mask=torch.ones(4, 4))


def test_nan_in_height_field() -> None:
    d = torch.zeros(4, 4, dtype=torch.float64)
    d[1, 2] = float("nan")
    with pytest.raises(ValueError, match="1 NaN"):
        PixelL1().prox(d, 0.1)


def test_missing_volume() -> None:
    ctx = RegularizerContext(mask=torch.ones(4, 4, dtype=torch.bool))
    with pytest.raises(ValueError, match=r"volume_v1 needs the deposited volume: set data\.volume="):
        VolumeHeuristic().setup(ctx)
    with pytest.raises(ValueError, match="volume_v2 needs the deposited volume"):
        VolumeSlabL1Bounds().setup(ctx)


@pytest.mark.parametrize("volume", [-1.0, 0.0, float("nan")])
def test_non_positive_volume(volume: float) -> None:
    with pytest.raises(ValueError, match=f"volume={volume!r}"):
        RegularizerContext(mask=torch.ones(4, 4, dtype=torch.bool), volume=volume)


@pytest.mark.parametrize("v_eps", [1.0, -0.1])
def test_volume_uncertainty_out_of_range(v_eps: float) -> None:
    with pytest.raises(ValueError, match=f"v_eps={v_eps!r}"):
        VolumeHeuristic(v_eps=v_eps)
    with pytest.raises(ValueError, match=f"v_eps={v_eps!r}"):
        VolumeSlabL1Bounds(v_eps=v_eps)


def test_unreachable_volume_band() -> None:
    ctx = RegularizerContext(mask=torch.ones(4, 4, dtype=torch.bool), volume=100.0)
    with pytest.raises(ValueError, match="unreachable with 16 mask pixels"):
        VolumeSlabL1Bounds(p2=0.3).setup(ctx)


def test_bad_step_and_alpha() -> None:
    with pytest.raises(ValueError, match="step.*-0.1"):
        PixelL1().prox(torch.zeros(2, 2), -0.1)
    with pytest.raises(ValueError, match="alpha.*-1"):
        PixelL1(alpha=-1.0)


def test_wavelet_grid_mode_and_family() -> None:
    with pytest.raises(ValueError, match=r"\(100, 100\).*2\*\*levels = 8"):
        WaveletTransform((100, 100), "db3", 3)
    with pytest.raises(ValueError, match="'symmetric'"):
        WaveletTransform((128, 128), mode="symmetric")
    with pytest.raises(ValueError, match="'bior2.2'"):
        WaveletTransform((128, 128), "bior2.2")
    with pytest.raises(ValueError, match=r"\(64, 64\)"):
        WaveletTransform((128, 128)).forward(torch.zeros(64, 64))


def test_use_before_setup() -> None:
    with pytest.raises(RuntimeError, match="call setup"):
        HeightBounds().prox(torch.zeros(2, 2), 1.0)
