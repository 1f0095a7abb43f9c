"""Every regularizer plugin is registered and builds with its defaults."""

from __future__ import annotations

import pytest
import torch

import regularizers
from framework import registry
from framework.registry import available, build
from regularizers import PostStepUpdate, Regularizer, RegularizerContext

NAMES = ["bounds", "l1_bounds", "l1_pixel", "l1_wavelet", "volume_v1", "volume_v2"]


@pytest.fixture(autouse=True)
def only_regularizer_plugins(monkeypatch: pytest.MonkeyPatch) -> None:
    """Load just this package's plugins, so these tests do not depend on other packages importing."""
    monkeypatch.setattr(registry, "BUILTIN_PLUGIN_MODULES", ("regularizers",))
    monkeypatch.setattr(registry, "_loaded", False)


def test_all_plugins_registered() -> None:
    assert set(NAMES) <= set(available("regularizer"))


@pytest.mark.parametrize("name", NAMES)
def test_build_setup_and_apply_with_defaults(name: str) -> None:
    m = 128
    plugin = build("regularizer", name)
    plugin.setup(RegularizerContext.full(m, volume=0.0669, pixel_area=(2 / m) ** 2))
    d = torch.full((m, m), 0.05, dtype=torch.float64)
    if isinstance(plugin, Regularizer):
        assert plugin.has_prox and not plugin.smooth
        out = plugin.prox(d, 0.1)
        assert isinstance(plugin.value(out), float)
    else:
        assert isinstance(plugin, PostStepUpdate)
        out = plugin(d)
    assert out.shape == (m, m) and out.dtype == torch.float64


def test_public_names_exported() -> None:
    for name in regularizers.__all__:
        assert hasattr(regularizers, name)
