"""Bad input gets a clear error naming the value."""

from __future__ import annotations

import pytest
import torch

from operators.emission import LightEmitter
from operators.materials import ConstantIndex
from operators.scene import Light, Receiver, Scene
from tests.operators.conftest import make_operator


@pytest.mark.parametrize("heights, message", [
    (torch.full((16, 16), float("nan")), "NaN"),
    (-0.2 * torch.ones(16, 16), "below the substrate bottom"),
    (torch.zeros(16, 12), "square"),
    (torch.zeros(16), "square"),
    (torch.full((16, 16), 20.0), "light"),
])
def test_bad_heights(heights, message):
    with pytest.raises(ValueError, match=message):
        make_operator().render(heights)


def test_bad_scenes():
    with pytest.raises(ValueError, match="receiver.z=0.2"):
        Receiver(z=0.2)
    with pytest.raises(ValueError, match="light.position z=0.05"):
        Scene(light=Light(position=(0.0, 0.0, 0.05)))
    with pytest.raises(ValueError, match="refractive index 0.9"):
        Scene(material=ConstantIndex(0.9))
    with pytest.raises(ValueError, match="wavelength -0.5"):
        Scene(wavelengths=(-0.5,))
    with pytest.raises(ValueError, match="photons=0"):
        LightEmitter(Scene(), 0, 0, 3.0)
    with pytest.raises(ValueError, match="dtype"):
        make_operator(dtype="float16")
    with pytest.raises(ValueError, match="hit_cache_mb=-1"):
        make_operator(hit_cache_mb=-1)


def test_target_of_wrong_shape():
    op = make_operator()
    with pytest.raises(ValueError, match="target has shape"):
        op.loss_and_grad(torch.zeros(16, 16), torch.zeros(1, 8, 8))
