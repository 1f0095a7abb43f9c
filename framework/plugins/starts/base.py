"""What a start plugin receives and returns.

A plugin of kind ``initial`` is built from its config group (``conf/initial/<name>.yaml``) by its
``from_config(**params)``, which checks every value before anything is rendered; the built object
is called once the data are loaded: ``start(request) -> StartResult``. A start that reads files
may also have ``check(base_dir)``, called before the run opens.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from torch import Tensor

if TYPE_CHECKING:
    from framework.core.problem import Problem

__all__ = ["StartRequest", "StartResult"]


@dataclass(frozen=True)
class StartRequest:
    """What a start may use.

    Attributes:
        problem: The operator, data (target, mask, volume, noise level), grid and scene.
        design: Builds the configured height field (m, m) (with synthetic data the ground truth).
        base_dir: Directory relative paths are resolved against.
    """

    problem: Problem
    design: Callable[[], Tensor]
    base_dir: Path


@dataclass
class StartResult:
    """A start d0 (m, m), scene units, in the operator's dtype, and what computing it measured
    (logged with the run as ``start_*`` metrics)."""

    d: Tensor
    metrics: dict[str, float] = field(default_factory=dict)
    name: str = ""
