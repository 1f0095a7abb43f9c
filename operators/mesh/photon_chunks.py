"""The photons the mesh scene's native path carries between event kernels (operators/mesh/trace_native.py):
those waiting above the print (Prefix), a chunk of photons under way, and the arrays each render
fills again per chunk (splat arguments, event logs).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from operators.mesh import events_compiled
from operators.mesh import kernels_native as mk

__all__ = ["PhotonChunk", "Prefix", "RenderBuffers", "write_back"]


@dataclass
class Prefix:
    """Photons before their first hit on the printed top: state (N, STATE), channel and events
    used so far (N,); the fixed image (c, n, n, flux per pixel) and losses (W) of all others.
    Within each chunk the photons are in the order they are traced and splatted in, by where they
    cross the plane z = thickness (:func:`operators.mesh.locality.crossing_order`); ``lowest``
    the lowest z at which one waits (inf for none)."""

    state: np.ndarray
    channel: np.ndarray
    events: np.ndarray
    image: torch.Tensor
    losses: dict[str, float]
    lowest: float


@dataclass
class PhotonChunk:
    """Photons under way: state (N, STATE), medium, channel, status, event count and whether
    they left a face with no element in front (N,)."""

    state: np.ndarray
    medium: np.ndarray
    channel: np.ndarray
    status: np.ndarray
    events: np.ndarray
    clear: np.ndarray

    @classmethod
    def starting(cls, state: np.ndarray, channel: np.ndarray, events: np.ndarray) -> PhotonChunk:
        """Photons in air, under way."""
        n = len(state)
        return cls(state, np.full(n, mk.AIR, dtype=np.int64), channel, np.full(n, mk.UNDER_WAY, dtype=np.int64),
                   events, np.zeros(n, dtype=np.bool_))

    def take(self, index: np.ndarray) -> PhotonChunk:
        """A copy of the photons at ``index``."""
        return PhotonChunk(self.state[index], self.medium[index], self.channel[index], self.status[index],
                      self.events[index], self.clear[index])


def write_back(chunk: PhotonChunk, index: np.ndarray | None, work: PhotonChunk) -> None:
    """Copy ``work`` (the chunk's photons at ``index``; None: the chunk itself) into the chunk."""
    if index is None:
        return
    chunk.state[index], chunk.medium[index], chunk.status[index], chunk.events[index], chunk.clear[index] = (
        work.state, work.medium, work.status, work.events, work.clear)


class RenderBuffers:
    """Arrays each render fills again, per chunk: its photons' splat arguments and event logs.
    The last render's are those its gradient reads; refilling them spares a render the page
    faults of new arrays."""

    def __init__(self) -> None:
        self._splats: dict[int, events_compiled.SplatArguments] = {}
        self._logs: dict[int, events_compiled.EventLog] = {}

    def splat(self, k: int, n: int) -> events_compiled.SplatArguments:
        """Chunk ``k``'s splat arguments for ``n`` photons."""
        if k not in self._splats or len(self._splats[k].flux) != n:
            self._splats[k] = events_compiled.SplatArguments.empty(n)
        return self._splats[k]

    def log(self, k: int, n: int, max_depth: int) -> events_compiled.EventLog:
        """Chunk ``k``'s event log for ``n`` photons of ``max_depth`` events."""
        if k not in self._logs or self._logs[k].kind.shape != (max_depth, n):
            self._logs[k] = events_compiled.EventLog.empty(n, max_depth)
        return self._logs[k]
