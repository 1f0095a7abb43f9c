"""The shared contract suite: every installed plugin of the kinds operator, regularizer and
post_step (built-ins and those other packages register through entry points) passes its kind's
checks (framework/core/contract_checks.py); so does the test suite's own operator; a deliberately
broken operator and regulariser fail them."""

from __future__ import annotations

import pytest
import torch

from framework.core.contract_checks import (ContractViolation, check_operator, check_post_step, check_regularizer,
                                       example_settings)
from framework.core.plugin_config import build_plugin
from framework.core.registry import available, lookup
from operators.scene import Receiver, Scene
from regularizers import PixelL1
from tests.plugins.trivial import ShadowOperator

SCENE = Scene(receiver=Receiver(resolution=32))


def _operator_maker(name: str, photons: int = 20_000):
    settings = example_settings(lookup("operator", name))
    return lambda seed: build_plugin("operator", name, settings, "operator", scene=SCENE, photons=photons, seed=seed)


@pytest.mark.parametrize("name", available("operator"))
def test_every_operator_keeps_the_contract(name) -> None:
    check_operator(_operator_maker(name), who=f"operator/{name}")


@pytest.mark.parametrize("name", available("regularizer"))
def test_every_regularizer_keeps_the_contract(name) -> None:
    plugin = lookup("regularizer", name)
    check_regularizer(build_plugin("regularizer", name, example_settings(plugin), "regularizer"),
                      who=f"regularizer/{name}")


@pytest.mark.parametrize("name", available("post_step"))
def test_every_post_step_keeps_the_contract(name) -> None:
    plugin = lookup("post_step", name)
    check_post_step(build_plugin("post_step", name, example_settings(plugin), "post_step"), who=f"post_step/{name}")


def test_the_test_suites_operator_keeps_the_contract() -> None:
    check_operator(lambda seed: ShadowOperator.from_config(SCENE, 1, seed), who="operator/shadow")


class _OffByATerm(ShadowOperator):
    """The shadow operator with a gradient that adds a term its image does not have."""

    def loss_and_grad(self, heights, target, image=None):
        loss, grad, image = super().loss_and_grad(heights, target, image)
        return loss, grad + 0.01 * heights, image


class _NoShrink(PixelL1):
    """An l1 regulariser whose prox forgets to shrink."""

    def prox(self, d: torch.Tensor, step: float) -> torch.Tensor:
        return d.clone()


def test_a_broken_operator_and_a_broken_regulariser_fail_the_contract() -> None:
    with pytest.raises(ContractViolation, match="differs from finite differences"):
        check_operator(lambda seed: _OffByATerm.from_config(SCENE, 1, seed), who="operator/off_by_a_term")
    with pytest.raises(ContractViolation, match="is not the minimiser"):
        check_regularizer(_NoShrink(alpha=0.1), who="regularizer/no_shrink")
