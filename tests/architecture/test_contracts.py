"""One contract per plugin kind: every kind has one base class, every base derives from
operators/plugin.py's Plugin (what the framework reads of any plugin class, declared once), no
Protocol restates what a base declares, and the registry only finds plugins: it reads nothing of
them (framework/core/registry.py calls no getattr)."""

from __future__ import annotations

import ast
from pathlib import Path

from framework.core.contracts.checks import BASES
from framework.core.registry import KINDS
from framework.optimization.preconditioner import GradientPreconditioner
from framework.optimization.step_size import StepSizePolicy
from operators.plugin import Plugin
from tests.architecture.import_graph import PACKAGES

ROOT = Path(__file__).resolve().parents[2]

# The Protocols the packages keep, none a plugin kind's: a callable's signature and a fit's misfit.
PROTOCOLS = {("framework/defects/fit.py", "Misfit"), ("operators/materials.py", "DispersionCurve")}


def _protocols(root: Path) -> set[tuple[str, str]]:
    """(file, class) of every class deriving from typing.Protocol in the project's packages."""
    found = set()
    for package in PACKAGES:
        for path in (root / package).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ClassDef) and any(
                        isinstance(b, ast.Name) and b.id == "Protocol" for b in node.bases):
                    found.add((path.relative_to(root).as_posix(), node.name))
    return found


def test_every_kind_has_one_base_and_every_base_is_a_plugin() -> None:
    bases = {**BASES, "step_size": StepSizePolicy, "preconditioner": GradientPreconditioner}
    assert set(bases) == set(KINDS)
    assert [kind for kind, base in bases.items() if not issubclass(base, Plugin)] == []


def test_no_protocol_restates_a_contract() -> None:
    assert _protocols(ROOT) == PROTOCOLS


def test_the_registry_reads_nothing_of_a_plugin() -> None:
    tree = ast.parse((ROOT / "framework" / "core" / "registry.py").read_text())
    calls = {node.func.id for node in ast.walk(tree) if isinstance(node, ast.Call) and isinstance(node.func, ast.Name)}
    assert not calls & {"getattr", "hasattr"}
