"""The mesh-scene operator's numerical settings: those of every photon operator
(operators/photon_settings.py) and the mesh scene's own (aperture, events per photon, kernels).
"""

from __future__ import annotations

from dataclasses import dataclass

from operators.photon_settings import PhotonSettings
from operators.values import checked_flag, checked_number, checked_whole

__all__ = ["MeshSceneSettings"]


@dataclass(frozen=True)
class MeshSceneSettings(PhotonSettings):
    """Numerical settings: those of every photon operator (:class:`operators.photon_settings.PhotonSettings`,
    footprints in receiver pixels; the kernels: the event kernels of operators/kernels/mesh_events.c
    or numba's) and

    max_depth: events (hits of a surface) a photon may have before it is dropped.
    aperture_half_width: half width of the square on the substrate top's plane the photons are
        aimed at, scene units or a length with a unit (None: the substrate's half width).
    native: trace with the event kernels (Embree on every thread); False: the torch tracer
        (autograd), the reference they are tested against.
    event_log_mb: memory (MiB) for the events a render with the C kernels records (13 bytes an
        event, ``max_depth`` events a photon), which a gradient at the same heights replays instead
        of searching again, and where they fit beside them the photons' splat arguments (56 bytes
        a photon), at which that gradient gathers the splat's adjoint; 0 turns it off.
    """

    photons: int = 1 << 20
    chunk_size: int = 1 << 17
    max_depth: int = 16
    aperture_half_width: float | None = None
    native: bool = True
    event_log_mb: float = 512.0

    def __post_init__(self) -> None:
        super().__post_init__()
        self._set("max_depth", checked_whole(self.max_depth, "operator.max_depth", 1))
        checked_flag(self.native, "operator.native")
        self._set("event_log_mb", checked_number(self.event_log_mb, "operator.event_log_mb", least=0.0,
                                                 unit="MiB; 0: off"))
        if self.aperture_half_width is not None:
            self._set("aperture_half_width", checked_number(self.aperture_half_width, "operator.aperture_half_width",
                                                            above=0.0, unit="scene units, or null"))
