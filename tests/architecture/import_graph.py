"""The project's import graph, read from the sources (every import statement, including those
inside functions and under TYPE_CHECKING), and what is wrong with it.

    python -m tests.architecture.import_graph [ROOT]     # prints the cycles and upward arrows
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

PACKAGES = ("framework", "operators", "regularizers", "experiments")
# Packages that must not import framework/ (physics and regularisers know nothing of the glue).
LOWER = ("operators", "regularizers")


def module_names(root: Path) -> dict[str, Path]:
    """Dotted module name -> file, for every .py file of the project's packages."""
    names = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            names[".".join(parts)] = path
    return names


def _targets(node: ast.AST, module: str, is_package: bool, known: set[str]) -> list[str]:
    if isinstance(node, ast.Import):
        candidates = [alias.name for alias in node.names]
    elif isinstance(node, ast.ImportFrom):
        base = node.module or ""
        if node.level:
            anchor = module.split(".")
            anchor = anchor if is_package else anchor[:-1]
            anchor = anchor[: len(anchor) - (node.level - 1)]
            base = ".".join([*anchor, *([base] if base else [])])
        candidates = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base for alias in node.names]
    else:
        return []
    out = []
    for name in candidates:
        while name and name not in known:  # import a.b.c of a module a.b: the arrow goes to a.b
            name = name.rpartition(".")[0]
        if name:
            out.append(name)
    return out


def import_graph(root: Path) -> dict[str, set[str]]:
    """Module -> the project's modules it imports."""
    files = module_names(root)
    known = set(files)
    graph: dict[str, set[str]] = {}
    for module, path in files.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        is_package = path.name == "__init__.py"
        graph[module] = {t for node in ast.walk(tree) for t in _targets(node, module, is_package, known)
                         if t != module}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


# The rooms of framework/. Shared rooms by level, lowest first: a module imports from its own room
# and from shared rooms of a lower level. A feature imports the shared rooms and, of the other
# features, only those FEATURE_USES names (tracks report defects). The reconstruction imports no
# feature: the stack, the defect report and the tracks join it as stages
# (framework/core/contracts/stage.py), the tracker as its run log (framework/core/contracts/run_log.py),
# the lab's calibration as framework/core/contracts/calibration.py.
SHARED = {"framework.core": 0, "framework.files": 1, "framework.scene": 2, "framework.data": 2,
          "framework.optimization": 2, "framework.representations": 2}
FEATURES = ("framework.reconstruction", "framework.design", "framework.lab", "framework.stack",
            "framework.defects", "framework.tracking", "framework.tracks")
FEATURE_USES = {"framework.tracks": {"framework.defects"}}


def room(module: str) -> str | None:
    """The room of framework/ that holds ``module`` (``framework.core`` ...), None outside framework/."""
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] == "framework" and len(parts) > 1 else None


def _may_import(a: str, b: str) -> bool:
    room_a, room_b = room(a), room(b)
    placed = set(SHARED) | set(FEATURES)
    if room_a not in placed or room_b not in placed or room_a == room_b:  # unplaced: unknown_rooms tells
        return True
    if room_b in SHARED:
        return room_a in FEATURES or (room_a in SHARED and SHARED[room_b] < SHARED[room_a])
    return room_b in FEATURE_USES.get(room_a, set())


def unknown_rooms(graph: dict[str, set[str]]) -> list[str]:
    """Modules of framework/ in no room of SHARED or FEATURES (a new folder must be placed)."""
    return sorted(m for m in graph if room(m) is not None and room(m) not in SHARED and room(m) not in FEATURES)


def upward_arrows(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    """Imports from operators/ or regularizers/ into framework/, between rooms of framework/
    against the rule above, and from the registry into the project."""
    arrows = [(a, b) for a, targets in graph.items() for b in targets
              if a.split(".")[0] in LOWER and b.split(".")[0] == "framework"]
    arrows += [(a, b) for a, targets in graph.items() for b in targets if not _may_import(a, b)]
    arrows += [("framework.core.registry", b) for b in graph.get("framework.core.registry", ())]
    return sorted(arrows)


def main(argv: list[str]) -> None:
    root = Path(argv[0]) if argv else Path(__file__).resolve().parents[2]
    graph = import_graph(root)
    print(f"{len(graph)} modules, {sum(map(len, graph.values()))} arrows")
    for component in cycles(graph):
        print("cycle:", " <-> ".join(component))
    for a, b in upward_arrows(graph):
        print(f"upward: {a} -> {b}")
    for module in unknown_rooms(graph):
        print(f"in no room: {module}")


if __name__ == "__main__":
    main(sys.argv[1:])
