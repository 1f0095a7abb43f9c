"""The settings every photon operator shares are checked alike (operators/photon_settings.py):
the height-field and the mesh-scene operator refuse the same bad values with the same line and
take the same good ones."""

from __future__ import annotations

import pytest

from operators.heightfield.operator import OperatorSettings
from operators.mesh.settings import MeshSceneSettings

BAD = [
    (dict(photons=10.5), r"^photons=10.5 must be an integer >= 1$"),
    (dict(photons=0), r"^photons=0 must be an integer >= 1$"),
    (dict(seed=float("nan")), r"^seed=nan must be an integer$"),
    (dict(chunk_size=True), r"^operator.chunk_size=True must be an integer >= 1$"),
    (dict(min_footprint_px=0.0), r"^operator.min_footprint_px=0.0 must be a positive number \(pixels\)$"),
    (dict(max_pixel_radius=float("inf")), r"^operator.max_pixel_radius=inf must be a positive number"),
    (dict(min_footprint_px=30.0), r"^need operator.min_footprint_px \(30.0\) < operator.max_pixel_radius \(20.0\)$"),
    (dict(footprint_px="wide"), r"^operator.footprint_px='wide' must be 'cell'"),
    (dict(fresnel=1), r"^operator.fresnel=1 must be true or false$"),
    (dict(pixel_integration="yes"), r"^operator.pixel_integration='yes' must be true or false$"),
    (dict(dtype="float16"), r"^operator.dtype='float16' is not supported; use float32 or float64$"),
    (dict(kernels="fortran"), r"^operator.kernels='fortran' must be one of c, numba$"),
]


@pytest.mark.parametrize("settings", [OperatorSettings, MeshSceneSettings])
@pytest.mark.parametrize("values, message", BAD)
def test_a_bad_shared_setting_is_refused_alike_by_every_photon_operator(settings, values, message) -> None:
    with pytest.raises(ValueError, match=message):
        settings(**values)


@pytest.mark.parametrize("settings", [OperatorSettings, MeshSceneSettings])
def test_a_whole_float_photon_count_is_taken_as_an_integer(settings) -> None:
    taken = settings(photons=1048576.0, chunk_size=65536.0, min_footprint_px=1)
    assert (taken.photons, taken.chunk_size) == (1048576, 65536)
    assert type(taken.photons) is int and type(taken.min_footprint_px) is float


def test_each_operator_keeps_its_own_defaults_and_checks() -> None:
    assert (OperatorSettings().photons, MeshSceneSettings().photons) == (1 << 22, 1 << 20)
    with pytest.raises(ValueError, match=r"^operator.hit_cache_mb=-1 must be a number >= 0 \(MiB"):
        OperatorSettings(hit_cache_mb=-1)
    with pytest.raises(ValueError, match=r"^operator.max_depth=0 must be an integer >= 1$"):
        MeshSceneSettings(max_depth=0)
