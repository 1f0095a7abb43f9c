"""Every regularizer and post-step plugin is declared and builds with its defaults."""

from __future__ import annotations

import pytest
import torch

import regularizers
from framework.core.plugin_config import build_plugin
from framework.core.registry import available
from regularizers import PostStepUpdate, Regularizer, RegularizerContext

PLUGINS = [("regularizer", "bounds"), ("regularizer", "l1_bounds"), ("regularizer", "l1_pixel"),
           ("regularizer", "l1_wavelet"), ("regularizer", "volume_v2"), ("post_step", "volume_v1"),
           ("post_step", "volume_hold")]


def test_all_plugins_declared() -> None:
    for kind, name in PLUGINS:
        assert name in available(kind), (kind, name)


@pytest.mark.parametrize("kind, name", PLUGINS)
def test_build_setup_and_apply_with_defaults(kind: str, name: str) -> None:
    m = 128
    plugin = build_plugin(kind, name, {}, name)
    plugin.setup(RegularizerContext.full(m, volume=0.0669, pixel_area=(2 / m) ** 2))
    d = torch.full((m, m), 0.05, dtype=torch.float64)
    if kind == "regularizer":
        assert isinstance(plugin, Regularizer) and plugin.has_prox and not plugin.smooth
        out = plugin.prox(d, 0.1)
        assert isinstance(plugin.value(out), float)
    else:
        assert isinstance(plugin, PostStepUpdate)
        out = plugin(d)
    assert out.shape == (m, m) and out.dtype == torch.float64


def test_public_names_exported() -> None:
    for name in regularizers.__all__:
        assert hasattr(regularizers, name)
