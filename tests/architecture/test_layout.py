"""Two rules of the layout: no module over 400 lines, and the type of a config value is checked by
the one family of value checks (operators/values.py), not by hand."""

from __future__ import annotations

import ast
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("framework", "operators", "regularizers", "experiments", "examples")
MAX_LINES = 400
FAMILY = Path("operators/values.py")


def _modules(root: Path) -> list[Path]:
    return [path for package in PACKAGES for path in sorted((root / package).rglob("*.py"))]


def hand_written_type_checks(root: Path) -> list[str]:
    """``file:line`` of every ``isinstance(x, bool)`` outside the family: the start of a value check
    written by hand (a bool passing for a number), which the family's checks make once."""
    found = []
    for path in _modules(root):
        if path.relative_to(root) == FAMILY:
            continue
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "isinstance"
                    and len(node.args) == 2 and isinstance(node.args[1], ast.Name) and node.args[1].id == "bool"):
                found.append(f"{path.relative_to(root)}:{node.lineno}")
    return found


def test_no_module_is_over_400_lines() -> None:
    long = {str(path.relative_to(ROOT)): n for path in _modules(ROOT)
            if (n := len(path.read_text().splitlines())) > MAX_LINES}
    assert long == {}


def test_values_are_checked_by_the_one_family() -> None:
    assert hand_written_type_checks(ROOT) == []


def test_a_hand_written_check_is_found(tmp_path: Path) -> None:
    (tmp_path / "framework").mkdir()
    (tmp_path / "framework" / "settings.py").write_text(textwrap.dedent('''
        def every(value):
            if isinstance(value, bool) or not isinstance(value, int):
                raise ValueError(value)
            return value
        '''))
    assert hand_written_type_checks(tmp_path) == ["framework/settings.py:3"]


STEP_NAMES = {"tau", "step", "t", "alpha", "lr"}


def _algorithm_sites(root: Path) -> tuple[set[str], set[str]]:
    """(modules of framework/ with a loop over ``reversed(...)``, the shape of the L-BFGS two-loop
    recursion; modules that shrink a step length by a factor inside a loop, the shape of a
    backtracking search)."""
    two_loop, backtracking = set(), set()
    for path in sorted((root / "framework").rglob("*.py")):
        name = str(path.relative_to(root))
        for loop in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if not isinstance(loop, (ast.For, ast.While)):
                continue
            if (isinstance(loop, ast.For) and isinstance(loop.iter, ast.Call) and isinstance(loop.iter.func, ast.Name)
                    and loop.iter.func.id == "reversed"):
                two_loop.add(name)
            for node in ast.walk(loop):
                if (isinstance(node, ast.AugAssign) and isinstance(node.op, (ast.Mult, ast.Div))
                        and isinstance(node.target, ast.Name) and node.target.id in STEP_NAMES
                        and isinstance(node.value, (ast.Name, ast.Constant, ast.Attribute))):  # by a factor
                    backtracking.add(name)
    return two_loop, backtracking


def test_one_lbfgs_and_one_backtracking_search() -> None:
    two_loop, backtracking = _algorithm_sites(ROOT)
    assert two_loop == {"framework/optimization/quasi_newton.py"}  # LbfgsMemory.direction
    assert backtracking == {"framework/optimization/step_size.py"}  # step_size.backtrack


def test_a_second_two_loop_and_backtracking_are_found(tmp_path: Path) -> None:
    (tmp_path / "framework").mkdir()
    (tmp_path / "framework" / "copy.py").write_text(textwrap.dedent('''
        def direction(pairs, q):
            for s, y in reversed(pairs):
                q = q - s
            return q

        def search(f, tau, shrink):
            while f(tau) > 0:
                tau *= shrink
            return tau
        '''))
    assert _algorithm_sites(tmp_path) == ({"framework/copy.py"}, {"framework/copy.py"})
