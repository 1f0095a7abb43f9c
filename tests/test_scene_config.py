"""Every config in conf/ composes and builds; overrides reach the scene; bad keys are refused."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir

from experiments.apps.configs import to_plain
from framework.scene.scene_config import build_heights, build_operator, build_scene
from framework.scene.printed_shapes import make_shape

CONF = Path(__file__).resolve().parents[1] / "conf"
SCENES = sorted(p.stem for p in (CONF / "scene").glob("*.yaml"))
# The prism and lens array builds a mesh of 4 s a case: those cases run in the full suite, not the fast lane.
OPERATOR_NAMES = sorted(p.stem for p in (CONF / "operator").glob("*.yaml"))
OPERATORS = [pytest.param(name, marks=pytest.mark.slow) if name == "prism_lens_array" else name
             for name in OPERATOR_NAMES]
SMALL = ["height_field.resolution=16", "receiver.resolution=32", "photons=3000"]


def compose_simulate(overrides: list[str]) -> dict[str, Any]:
    with initialize_config_dir(version_base=None, config_dir=str(CONF)):
        return to_plain(compose(config_name="simulate", overrides=overrides))


def plain(**groups: Any) -> dict[str, Any]:
    """A minimal valid config as plain dicts, with ``groups`` replacing top-level keys."""
    cfg: dict[str, Any] = {"light": {"position": [0, 0, 10], "power": 1.0},
                           "substrate": {"thickness": 0.1, "half_width": 1.0},
                           "receiver": {"z": -0.05, "resolution": 32, "half_width": 1.0},
                           "material": {"kind": "fused_silica"}, "wavelengths": [0.633],
                           "height_field": {"shape": "flat", "resolution": 8},
                           "photons": 1000, "seed": 0, "operator": {"name": "height_field"}}
    cfg.update(groups)
    return cfg


def test_the_expected_configs_exist() -> None:
    assert SCENES == ["bump", "flat", "gaussian", "letter_a", "oblique_lines", "print_lines", "print_lines_mm"]
    assert OPERATOR_NAMES == ["height_field", "mesh_scene", "prism_lens_array", "two_lenses"]


@pytest.mark.parametrize("operator", OPERATORS)
@pytest.mark.parametrize("scene_name", SCENES)
def test_every_config_composes_and_builds(scene_name: str, operator: str) -> None:
    cfg = compose_simulate([f"scene={scene_name}", f"operator={operator}"] + SMALL)
    scene = build_scene(cfg)
    heights = build_heights(cfg)
    op = build_operator(cfg, scene)
    shape = scene_name.removesuffix("_mm")  # print_lines_mm: the same scene with lengths in mm
    assert cfg["height_field"]["shape"] == shape
    assert heights.shape == (16, 16) and heights.dtype == torch.float64
    np.testing.assert_array_equal(heights.numpy(), make_shape(shape, 16, **cfg["height_field"]["params"]))
    channels = len(cfg["wavelengths"])
    assert op.output_shape == (channels, 32, 32)
    image = op.render(heights)
    assert image.shape == (channels, 32, 32) and bool(torch.isfinite(image).all()) and float(image.sum()) > 0


def test_defaults_are_the_official_ones() -> None:
    cfg = compose_simulate([])
    scene = build_scene(cfg)
    assert scene.light.position == (0.0, 0.0, 10.0) and scene.light.power == 1.0
    assert scene.substrate.thickness == 0.1
    assert (scene.receiver.z, scene.receiver.resolution) == (-0.05, 512)
    assert scene.wavelengths == (0.633,) and scene.indices[0] == pytest.approx(1.4570, abs=1e-4)
    assert cfg["height_field"]["resolution"] == 128 and cfg["height_field"]["shape"] == "print_lines"
    assert cfg["photons"] == 4194304 and cfg["seed"] == 0
    op = build_operator(cfg, scene)
    s = op.fine.settings  # the fine operator's: 4 x 4 fine pixels per receiver pixel, footprints in fine pixels
    assert op.factor == 4 and op.output_shape == (1, 512, 512) and op.fine.output_shape == (1, 2048, 2048)
    assert (s.footprint_px, s.min_footprint_px, s.max_pixel_radius, s.chunk_size) == ("cell", 0.4, 80, 262144)
    assert (s.fresnel, s.dtype, s.device, s.photons) == (False, "float32", "cpu", 4194304)


def test_command_line_style_overrides_reach_the_scene(tmp_path: Path) -> None:
    np.save(tmp_path / "d.npy", np.full((8, 8), 0.02))
    cfg = compose_simulate(["light.position=[0,0,5]", "wavelengths=[0.475,0.5625,0.65]", "receiver.z=-0.2",
                            "photons=999", f"height_field.path={tmp_path / 'd.npy'}", "height_field.resolution=8",
                            "operator.dtype=float64", "seed=3"])
    scene = build_scene(cfg)
    assert scene.light.position == (0.0, 0.0, 5.0) and scene.channels == 3 and scene.receiver.z == -0.2
    op = build_operator(cfg, scene)
    assert op.fine.settings.photons == 999 and op.fine.settings.seed == 3 and op.dtype == torch.float64
    np.testing.assert_allclose(build_heights(cfg).numpy(), 0.02)


def test_relative_path_is_resolved_against_base_dir(tmp_path: Path) -> None:
    np.save(tmp_path / "d.npy", np.full((8, 8), 0.01))
    cfg = plain(height_field={"path": "d.npy", "resolution": 8, "scale": 2.0})
    np.testing.assert_allclose(build_heights(cfg, base_dir=tmp_path).numpy(), 0.02)


def test_scale_multiplies_a_shape() -> None:
    cfg = plain(height_field={"shape": "gaussian", "resolution": 9, "scale": 0.5})
    np.testing.assert_allclose(build_heights(cfg).numpy(), 0.5 * make_shape("gaussian", 9))


def test_other_materials_build() -> None:
    assert build_scene(plain(material={"kind": "constant", "n": 1.5})).indices == (1.5,)
    cauchy = build_scene(plain(material={"kind": "cauchy", "a": 1.45, "b": 0.0036}))
    assert cauchy.indices[0] == pytest.approx(1.45 + 0.0036 / 0.633 ** 2)
    sellmeier = build_scene(plain(material={"kind": "sellmeier", "b": [0.6961663, 0.4079426, 0.8974794],
                                            "c": [0.0684043, 0.1162414, 9.896161]}))
    assert sellmeier.indices[0] == pytest.approx(1.4570, abs=1e-4)


def test_struct_mode_refuses_unknown_override() -> None:
    with pytest.raises(Exception, match="colour"):
        compose_simulate(["light.colour=red"])


@pytest.mark.parametrize("groups, message", [
    ({"light": {"position": [0, 0, 10], "colour": "red"}}, "unknown key light.colour"),
    ({"receiver": {"z": -0.05, "pixels": 64}}, "unknown key receiver.pixels"),
    ({"substrate": {"thickness": 0.1, "width": 2}}, "unknown key substrate.width"),
    ({"material": {"kind": "constant", "n": 1.5, "k": 0.1}}, "unknown key material.k"),
    ({"material": {"kind": "unobtainium"}}, "unknown material.kind 'unobtainium'"),
    ({"material": {"kind": "sellmeier", "b": [1.0]}}, "needs material.c"),
    ({"light": {"position": [0, 10]}}, "light.position=\\[0, 10\\] must be \\[x, y, z\\]"),
    ({"light": {"position": [0, 0, 10], "power": "lots"}}, "light.power='lots' must be a number"),
    ({"receiver": {"resolution": 64.5}}, "receiver.resolution=64.5 must be an integer"),
    ({"receiver": {"z": 0.5}}, "receiver.z=0.5"),
    ({"wavelengths": [0.633, -1.0]}, "wavelength -1.0"),
    ({"wavelengths": "red"}, "wavelengths='red'"),
    ({"light": {"position": [0, 0, 0.05]}}, "above the substrate top"),
])
def test_bad_scene_configs_name_the_culprit(groups: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        build_scene(plain(**groups))


@pytest.mark.parametrize("groups, message", [
    ({"height_field": {"shape": "spiral"}}, "unknown shape 'spiral'; known shapes: bump, flat"),
    ({"height_field": {"resolution": 8}}, "needs a shape"),
    ({"height_field": {"shape": "flat", "size": 8}}, "unknown key height_field.size"),
    ({"height_field": {"shape": "bump", "params": {"radius": 1}}}, "no parameter 'radius'"),
    ({"height_field": {"shape": "flat", "resolution": 8.5}}, "height_field.resolution=8.5"),
    ({"height_field": {"path": "/no/such/file.npy"}}, "/no/such/file.npy"),
])
def test_bad_height_field_configs(groups: dict[str, Any], message: str) -> None:
    with pytest.raises((ValueError, FileNotFoundError), match=message):
        build_heights(plain(**groups))


@pytest.mark.parametrize("groups, message", [
    ({"photons": 0}, "photons=0 is too few"),
    ({"operator": {"name": "height_field", "footprint": 3}}, "unknown key operator.footprint"),
    ({"operator": {"footprint_px": 3}}, "operator needs a plugin name"),
    ({"operator": {"name": "raytracer"}}, "unknown operator plugin 'raytracer'; operator plugins: height_field"),
    ({"photons": 10.5}, "photons=10.5 must be an integer"),
    ({"operator": {"name": "height_field", "dtype": "float16"}}, "dtype='float16'"),
    ({"operator": {"name": "height_field", "device": "gpu0"}}, "operator.device='gpu0'"),
    ({"operator": {"name": "height_field", "fresnel": "yes"}}, "operator.fresnel='yes'"),
    ({"operator": {"name": "height_field", "simd": "on"}}, "operator.simd='on' must be true or false"),
    ({"operator": {"name": "height_field", "kernels": "fast"}}, "operator.kernels='fast' must be one of c, numba"),
    ({"operator": {"name": "height_field", "chunk_size": 0}}, "chunk_size=0"),
])
def test_bad_operator_configs(groups: dict[str, Any], message: str) -> None:
    cfg = plain(**groups)
    with pytest.raises((ValueError, KeyError), match=message):
        build_operator(cfg, build_scene(cfg))
