"""The configuration is read at the edge: a reconstruction hands it to each module at most twice
(tests/architecture/config_path.py)."""

from __future__ import annotations

import pytest

from tests.architecture.config_path import small_run_calls, stays


def test_stays_are_counted_per_run_of_calls():
    calls = [("a", "f"), ("a", "g"), ("b", "h"), ("a", "f")]
    assert stays(calls) == {"a": 2, "b": 1}


@pytest.mark.slow
def test_a_reconstruction_hands_its_config_to_each_module_at_most_twice(tmp_path):
    visits = stays(small_run_calls(tmp_path))
    assert "framework.scene.run_settings" in visits and "framework.scene.scene_config" in visits  # it is traced
    assert max(visits.values()) <= 2, visits
