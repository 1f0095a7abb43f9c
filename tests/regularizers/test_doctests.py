"""The examples in the regularizer docstrings run and give what they show."""

from __future__ import annotations

import doctest

import pytest

import regularizers.shrinkage


@pytest.mark.parametrize("module", [regularizers.shrinkage])
def test_docstring_examples(module) -> None:
    result = doctest.testmod(module, extraglobs={"torch": __import__("torch")})
    assert result.failed == 0 and result.attempted > 0
