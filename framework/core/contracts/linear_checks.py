"""The contract of a linear piece of the image chain (operators/linear/linear_map.py): its adjoint
passes the dot test and its declared output shape is the one it gives.

tests/test_plugin_contracts.py runs :func:`check_linear_map` on every subclass of
:class:`operators.linear.LinearMap` that the project and its examples define, each through the
instance its ``example()`` gives; a package with its own pieces may call it from its tests.
"""

from __future__ import annotations

from framework.core.contracts.violation import ContractViolation
from operators.linear import LinearMap, dot_test

__all__ = ["DOT_TOLERANCE", "check_linear_map"]

DOT_TOLERANCE = 1e-12  # the dot test's mismatch in float64: rounding is about 1e-16


def check_linear_map(piece: type[LinearMap], seeds: int = 3) -> None:
    """``piece.example()`` passes :func:`operators.linear.dot_test` for ``seeds`` random pairs;
    a :class:`ContractViolation` names the piece and the mismatch otherwise."""
    instance, shape = piece.example()
    if not isinstance(instance, piece):
        raise ContractViolation(f"{piece.__qualname__}.example() gives a {type(instance).__qualname__}, not a "
                             f"{piece.__qualname__}")
    for seed in range(seeds):
        mismatch = dot_test(instance, shape, seed)
        if not mismatch <= DOT_TOLERANCE:
            raise ContractViolation(f"{piece.__module__}.{piece.__qualname__}: <L x, y> and <x, L^T y> differ by "
                                 f"{mismatch:.3g} (relative) for an input of shape {shape}; its adjoint is not "
                                 f"the transpose of apply")
