"""The arrows between the project's modules run one way: no circle, nothing from operators/ or
regularizers/ into framework/, nothing from framework/core into framework/plugins or
framework/pipeline nor from framework/plugins into framework/pipeline, and the plugin registry
imports nothing of the project."""

from __future__ import annotations

from pathlib import Path

from tests.architecture.import_graph import cycles, import_graph, upward_arrows

ROOT = Path(__file__).resolve().parents[2]


def test_the_graph_sees_the_known_arrows():
    graph = import_graph(ROOT)
    assert "framework.core.registry" in graph["framework.core.plugin_config"]
    assert "operators.scene" in graph["framework.core.scene_config"]
    assert "framework.plugins.starts.auto" in graph["framework.plugins.starts"]  # a relative import of a package


def test_a_circle_and_an_upward_arrow_are_found():
    graph = {"framework.a": {"framework.b"}, "framework.b": {"framework.a"}, "operators.x": {"framework.a"},
             "framework.core.registry": {"operators.x"}, "framework.core.y": {"framework.plugins.z"},
             "framework.plugins.z": {"framework.pipeline.w", "framework.core.y"}}
    assert cycles(graph) == [["framework.a", "framework.b"], ["framework.core.y", "framework.plugins.z"]]
    assert upward_arrows(graph) == [("framework.core.registry", "operators.x"),
                                    ("framework.core.y", "framework.plugins.z"),
                                    ("framework.plugins.z", "framework.pipeline.w"), ("operators.x", "framework.a")]


def test_no_circle_and_no_upward_arrow():
    graph = import_graph(ROOT)
    assert cycles(graph) == []
    assert upward_arrows(graph) == []


# The one plugin the pipelines build by its class: the design's stopping rule at the model's own
# noise (a config's stopping.morozov reads the data's noise, which a design target does not have).
BUILT_BY_CLASS = {("framework.pipeline.design_run", "framework.plugins.stopping")}


def test_the_pipelines_build_plugins_through_the_registry():
    graph = import_graph(ROOT)
    direct = {(module, target) for module, targets in graph.items() if module.startswith("framework.pipeline")
              for target in targets if target.startswith("framework.plugins")}
    assert direct == BUILT_BY_CLASS
