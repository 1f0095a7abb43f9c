"""Where the sources look up a member by name instead of using a declared one: ``__getattr__``
forwarding, and ``getattr`` / ``hasattr`` with a literal member name (a capability probe).

Plugins declare what they have on their kind's base (operators/plugin.py and the bases deriving
from it: framework/core/contracts/, regularizers/base.py; docs/plugins.md), and the framework reads
those attributes directly. Objects of other libraries, which declare nothing, are the only place a
member is probed.

    python -m tests.architecture.probes [ROOT]     # prints every probe and forwarding
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

from tests.architecture.import_graph import PACKAGES

# (file, member): the probes of other libraries' objects, each with its reason.
OTHER_LIBRARIES = {
    ("framework/files/mm_outputs.py", "text"): "a PIL image's text chunks (absent on some formats)",
    ("framework/lab/photo_import.py", "tag_v2"): "a PIL image's TIFF tags (absent on other formats)",
    ("framework/tracking/mlflow_tracker.py", "__spec__"): "the __main__ module's spec (absent when run as a script)",
    ("framework/tracking/tracking_target.py", "reason"): "a urllib error's reason (absent on some errors)",
    ("operators/heightfield/trace_cuda.py", "ENABLE_CUDASIM"): "numba's configuration (absent in old releases)",
    ("operators/heightfield/trace_cuda.py", "implementation"): "numba.cuda's driver (absent without CUDA)",
    ("experiments/apps/export.py", "problem_mark"): "a YAML error's position (absent on some errors)",
}


def probes(root: Path) -> list[tuple[str, int, str, str | None]]:
    """(file, line, what, member) of every ``__getattr__`` definition and every ``getattr`` /
    ``hasattr`` call with a literal member name in the project's packages."""
    found = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            name = path.relative_to(root).as_posix()
            for node in ast.walk(ast.parse(path.read_text(), filename=name)):
                if isinstance(node, ast.FunctionDef) and node.name == "__getattr__":
                    found.append((name, node.lineno, "__getattr__", None))
                elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                      and node.func.id in ("getattr", "hasattr") and len(node.args) >= 2
                      and isinstance(node.args[1], ast.Constant)):
                    found.append((name, node.lineno, node.func.id, str(node.args[1].value)))
    return found


def unexplained(root: Path) -> list[tuple[str, int, str, str | None]]:
    """The probes that :data:`OTHER_LIBRARIES` does not explain."""
    return [p for p in probes(root) if (p[0], p[3]) not in OTHER_LIBRARIES and (p[0], None) not in OTHER_LIBRARIES]


if __name__ == "__main__":
    for file, line, what, member in probes(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(".")):
        print(f"{file}:{line}: {what} {member or ''}")
