"""Plugins are used by what they declare, never probed (tests/architecture/probes.py)."""

from __future__ import annotations

import textwrap
from pathlib import Path

from tests.architecture.probes import OTHER_LIBRARIES, probes, unexplained

ROOT = Path(__file__).resolve().parents[2]


def test_no_member_is_probed_or_forwarded_outside_other_libraries() -> None:
    assert unexplained(ROOT) == []


def test_every_explained_probe_is_still_there() -> None:
    found = {(file, member) for file, _, _, member in probes(ROOT)}
    stale = [key for key in OTHER_LIBRARIES if key[1] is not None and key not in found]
    assert stale == []


def test_a_probe_and_a_forwarding_are_found(tmp_path: Path) -> None:
    (tmp_path / "framework").mkdir()
    (tmp_path / "framework" / "wrapper.py").write_text(textwrap.dedent('''
        class Wrapper:
            def __getattr__(self, name):
                return getattr(self.inner, name)

        def gain(operator):
            return getattr(operator, "gain", 1.0) if hasattr(operator, "gain") else 1.0
        '''))
    assert sorted((what, member or "") for _, _, what, member in probes(tmp_path)) == [
        ("__getattr__", ""), ("getattr", "gain"), ("hasattr", "gain")]
