"""The arrows between the project's modules run one way: no circle, nothing from operators/ or
regularizers/ into framework/, between the rooms of framework/ only as
tests/architecture/import_graph.py allows (shared rooms by level, a feature into another only where
FEATURE_USES says so), the pipelines build plugins only through the registry, and the plugin
registry imports nothing of the project."""

from __future__ import annotations

import tomllib
from pathlib import Path

from tests.architecture.import_graph import FEATURES, cycles, import_graph, room, unknown_rooms, upward_arrows

ROOT = Path(__file__).resolve().parents[2]


def test_the_graph_sees_the_known_arrows():
    graph = import_graph(ROOT)
    assert "framework.core.registry" in graph["framework.core.plugin_config"]
    assert "operators.scene" in graph["framework.scene.scene_config"]
    # a relative import of a package
    assert "framework.reconstruction.starts.auto" in graph["framework.reconstruction.starts"]


def test_a_circle_and_an_arrow_against_the_rooms_are_found():
    graph = {"framework.a": {"framework.b"}, "framework.b": {"framework.a"}, "operators.x": {"framework.core.y"},
             "framework.core.registry": {"operators.x"}, "framework.core.y": {"framework.files.z"},
             "framework.files.z": {"framework.core.y"}, "framework.lab.p": {"framework.stack.q", "framework.files.z"},
             "framework.tracks.r": {"framework.defects.q"}, "framework.scene.s": {"framework.data.t"},
             "framework.stack.q": {}, "framework.data.t": {}, "framework.plugins.u": {},
             "framework.defects.q": {}}
    assert cycles(graph) == [["framework.a", "framework.b"], ["framework.core.y", "framework.files.z"]]
    assert upward_arrows(graph) == [("framework.core.registry", "operators.x"),
                                    ("framework.core.y", "framework.files.z"),
                                    ("framework.lab.p", "framework.stack.q"),
                                    ("framework.scene.s", "framework.data.t"), ("operators.x", "framework.core.y")]
    assert unknown_rooms(graph) == ["framework.a", "framework.b", "framework.plugins.u"]


def test_no_circle_and_no_arrow_against_the_rooms():
    graph = import_graph(ROOT)
    assert cycles(graph) == []
    assert upward_arrows(graph) == []
    assert unknown_rooms(graph) == []


def test_the_reconstruction_imports_no_feature():
    """Features join a reconstruction as plugins (stages, the run log, the calibration), never by import."""
    graph = import_graph(ROOT)
    arrows = sorted((a, b) for a, targets in graph.items() if room(a) == "framework.reconstruction"
                    for b in targets if room(b) in FEATURES and room(b) != "framework.reconstruction")
    assert arrows == []


def _plugin_modules() -> set[str]:
    """The modules that pyproject.toml's entry points name."""
    groups = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]
    return {value.split(":")[0] for group in groups.values() for value in group.values()}


def _plugin_part(module: str) -> bool:
    """A module that builds plugins of its own (a solver's parts, the starts' package, the shared
    optimisation pieces): it may subclass and compose the plugin classes it is made of."""
    parts = module.split(".")
    return parts[:2] == ["framework", "optimization"] or "solvers" in parts or "starts" in parts


def test_the_pipelines_build_plugins_through_the_registry():
    plugins, graph = _plugin_modules(), import_graph(ROOT)
    assert {"framework.reconstruction.stopping", "framework.data.sources"} <= plugins
    direct = {(module, target) for module, targets in graph.items() if module.startswith("framework.")
              and module not in plugins and not _plugin_part(module) for target in targets & plugins}
    assert direct == set()

