"""Lengths and volumes with units (framework/core/units.py)."""

from __future__ import annotations

import pytest

from framework.scene.scene_config import build_scene
from framework.core.units import mm_per_unit, scene_length, scene_volume


def test_lengths_and_volumes_convert_with_the_scene_scale() -> None:
    assert scene_length("2.5 mm", 25.0, "x") == pytest.approx(0.1)
    assert scene_length("0.25cm", 25.0, "x") == pytest.approx(0.1)
    assert scene_length("2500 um", 25.0, "x") == pytest.approx(0.1)
    assert scene_length(0.3, 25.0, "x") == 0.3  # bare numbers are scene units
    assert scene_volume("15.625 mm3", 25.0, "v") == pytest.approx(1e-3)
    assert scene_volume("15.625 mm^3", 25.0, "v") == pytest.approx(1e-3)


def test_a_scene_given_in_millimetres_equals_the_one_in_scene_units() -> None:
    in_units = build_scene({"substrate": {"thickness": 0.1, "half_width": 1.0},
                            "receiver": {"z": -0.05, "resolution": 64, "half_width": 1.0},
                            "light": {"position": [0.0, 0.0, 10.0]}})
    in_mm = build_scene({"units": {"mm_per_unit": 25.0},
                         "substrate": {"thickness": "2.5 mm", "half_width": "25 mm"},
                         "receiver": {"z": "-1.25 mm", "resolution": 64, "half_width": "2.5 cm"},
                         "light": {"position": ["0 mm", 0.0, "0.25 m"]}})
    assert in_mm.substrate.thickness == pytest.approx(in_units.substrate.thickness)
    assert in_mm.receiver.z == pytest.approx(in_units.receiver.z)
    assert in_mm.light.position[2] == pytest.approx(10.0)


@pytest.mark.parametrize("cfg, match", [
    ({"units": {"mm_per_unit": 0}}, r"units.mm_per_unit=0 must be a length > 0"),
    ({"units": {"mm_per_unit": -3.0}}, r"units.mm_per_unit=-3.0"),
    ({"units": {"mm_per_unit": "25"}}, r"units.mm_per_unit='25'"),
    ({"units": {"mm": 25}}, "unknown key units.mm"),
])
def test_bad_units_are_refused(cfg, match) -> None:
    with pytest.raises(ValueError, match=match):
        mm_per_unit(cfg)


@pytest.mark.parametrize(
    "value, match", [("2.5 inch", "'2.5 inch'"), ("mm", "'mm'"), ("2 mm3", "'2 mm3'"), (True, "True")]
)
def test_bad_lengths_are_refused(value, match) -> None:
    with pytest.raises(ValueError, match=match):
        scene_length(value, 25.0, "substrate.thickness")


def test_the_paper_sample_in_millimetres_is_the_scene_in_units() -> None:
    from pathlib import Path

    from hydra import compose, initialize_config_dir

    from experiments.apps.configs import to_plain

    conf = str(Path(__file__).resolve().parents[2] / "conf")
    with initialize_config_dir(config_dir=conf, version_base=None):
        in_mm, in_units = (build_scene(to_plain(compose("reconstruct", overrides=[f"scene={name}"])))
                           for name in ("print_lines_mm", "print_lines"))
    assert in_mm == in_units
