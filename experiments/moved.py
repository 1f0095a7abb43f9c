"""The old flat module names of experiments/ kept working for one release.

The commands, the paper's scripts and the benchmarks live in experiments/apps/, experiments/paper/
and experiments/benchmarks/; ``python -m experiments.reproduce_table1`` (or an import of
``experiments.reproduce_table1``) still runs ``experiments.paper.reproduce_table1``, after one line
on standard error that names the new module. The old names go in the next release.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.util
import pkgutil
import sys
from collections.abc import Sequence
from pathlib import Path

__all__ = ["FOLDERS", "MovedModules", "install", "new_name"]

FOLDERS = ("apps", "paper", "benchmarks")


def new_name(name: str) -> str | None:
    """``experiments.<folder>.<name>`` for an old ``experiments.<name>``, or None where no folder holds it."""
    root = Path(__file__).parent
    for folder in FOLDERS:
        if name in {module.name for module in pkgutil.iter_modules([str(root / folder)])}:
            return f"experiments.{folder}.{name}"
    return None


class MovedModules(importlib.abc.MetaPathFinder):
    """Finds ``experiments.<name>`` where only ``experiments.<folder>.<name>`` exists (module docstring)."""

    def find_spec(self, fullname: str, path: Sequence[str] | None = None, target: object = None
                  ) -> importlib.machinery.ModuleSpec | None:
        package, _, name = fullname.partition(".")
        if package != "experiments" or not name or "." in name:
            return None
        moved = new_name(name)
        spec = None if moved is None else importlib.util.find_spec(moved)
        if spec is None or spec.origin is None:
            return None
        print(f"deprecated: {fullname} is now {moved}; the old name goes in the next release", file=sys.stderr)
        return importlib.util.spec_from_file_location(fullname, spec.origin)


def install() -> None:
    """Put :class:`MovedModules` after the standard finders (once)."""
    if not any(isinstance(finder, MovedModules) for finder in sys.meta_path):
        sys.meta_path.append(MovedModules())
