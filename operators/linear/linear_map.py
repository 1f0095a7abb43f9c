"""The base of the image chain's linear pieces: a linear map with its adjoint, composition, and the
dot test every piece passes.

A :class:`LinearMap` L takes a tensor x (an image (c, n, n), a stack of them) to L x and gives the
adjoint L^T y, so that <L x, y> = <x, L^T y> for every x and y. Maps compose with ``@`` as matrices
do: ``(A @ B).apply(x) = A.apply(B.apply(x))`` and ``(A @ B).adjoint(y) = B.adjoint(A.adjoint(y))``;
a number times a map is the map followed by a :class:`Gain`.
A camera's chain is written as one expression (operators/imaging.py: G = gain A K F), and its
gradient is the chain's adjoint applied to the image gradient before the photon operator's vjp.

Every concrete piece declares :meth:`LinearMap.example`, a small instance and the shape of its input,
so that :func:`dot_test` runs on all of them (tests/operators/test_linear_maps.py finds every
subclass); a new piece is checked the moment it is defined.
"""

from __future__ import annotations

import inspect
from abc import ABC, abstractmethod
from collections.abc import Sequence

import torch

from operators.values import checked_number

__all__ = ["Composition", "Gain", "LinearMap", "all_linear_maps", "dot_test"]


class LinearMap(ABC):
    """A linear map of tensors and its adjoint (module docstring)."""

    @abstractmethod
    def apply(self, x: torch.Tensor) -> torch.Tensor:
        """L x."""

    @abstractmethod
    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        """L^T y."""

    def output_shape(self, input_shape: tuple[int, ...]) -> tuple[int, ...]:
        """The shape of L x for an x of ``input_shape`` (the same unless a piece resamples)."""
        return tuple(input_shape)

    @classmethod
    @abstractmethod
    def example(cls) -> tuple[LinearMap, tuple[int, ...]]:
        """A small instance and the shape of an input it takes, for the dot test."""

    def __matmul__(self, other: LinearMap) -> Composition:
        if not isinstance(other, LinearMap):
            return NotImplemented
        return Composition([self, other])

    def __rmul__(self, gain: float) -> Composition:
        return Composition([Gain(gain), self])


class Gain(LinearMap):
    """x -> gain x, gain > 0: a camera's exposure gain (image units per W per scene unit^2);
    self-adjoint."""

    def __init__(self, gain: float) -> None:
        self.gain = checked_number(gain, "gain", above=0.0, unit="image units per W per scene unit^2")

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        return self.gain * x

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        return self.gain * y

    @classmethod
    def example(cls) -> tuple[LinearMap, tuple[int, ...]]:
        return cls(1.7), (2, 5, 5)


class Composition(LinearMap):
    """``maps[0] @ maps[1] @ ... @ maps[-1]``: the last applied first; nested compositions are
    flattened, so the pieces of a chain are :attr:`maps`, in the order they are written."""

    def __init__(self, maps: Sequence[LinearMap]) -> None:
        flat: list[LinearMap] = []
        for piece in maps:
            flat.extend(piece.maps if isinstance(piece, Composition) else [piece])
        if not flat:
            raise ValueError("a composition needs at least one linear map")
        self.maps = tuple(flat)

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        for piece in reversed(self.maps):
            x = piece.apply(x)
        return x

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        for piece in self.maps:
            y = piece.adjoint(y)
        return y

    def output_shape(self, input_shape: tuple[int, ...]) -> tuple[int, ...]:
        shape = tuple(input_shape)
        for piece in reversed(self.maps):
            shape = piece.output_shape(shape)
        return shape

    @classmethod
    def example(cls) -> tuple[LinearMap, tuple[int, ...]]:
        """Two gains (the pieces' order in a chain is tested with the image chain's own pieces,
        tests/operators/test_linear_maps.py)."""
        return Gain(1.5) @ Gain(0.5), (2, 4, 4)


def dot_test(linear_map: LinearMap, input_shape: tuple[int, ...], seed: int = 0) -> float:
    """|<L x, y> - <x, L^T y>| / (||L x|| ||y|| + ||x|| ||L^T y||) for random float64 x of
    ``input_shape`` and y of L's output shape: rounding (about 1e-16) for a map whose adjoint is
    right, order one for a wrong one."""
    generator = torch.Generator().manual_seed(seed)
    x = torch.randn(input_shape, generator=generator, dtype=torch.float64)
    y = torch.randn(linear_map.output_shape(tuple(input_shape)), generator=generator, dtype=torch.float64)
    forward, backward = linear_map.apply(x), linear_map.adjoint(y)
    if tuple(forward.shape) != tuple(y.shape) or tuple(backward.shape) != tuple(x.shape):
        raise ValueError(f"{type(linear_map).__name__} maps {tuple(x.shape)} to {tuple(forward.shape)} and back "
                         f"to {tuple(backward.shape)}; output_shape says {tuple(y.shape)}")
    scale = float(forward.norm() * y.norm() + x.norm() * backward.norm())
    return abs(float((forward * y).sum()) - float((x * backward).sum())) / max(scale, 1e-300)


def all_linear_maps() -> list[type[LinearMap]]:
    """Every concrete subclass of :class:`LinearMap` defined so far (imported modules only), by name."""
    found: dict[str, type[LinearMap]] = {}
    todo: list[type[LinearMap]] = [LinearMap]
    while todo:
        cls = todo.pop()
        for sub in cls.__subclasses__():
            todo.append(sub)
            if not inspect.isabstract(sub):
                found[f"{sub.__module__}.{sub.__qualname__}"] = sub
    return [found[name] for name in sorted(found)]
