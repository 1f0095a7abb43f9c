"""The mesh-scene operator's native path: photons traced event by event by the event kernels,
which ask Embree for faces on their own threads: those in C (:mod:`operators.mesh.events_compiled`,
compiled at install) or their numba twins (:mod:`operators.mesh.kernels_native`,
:mod:`operators.mesh.adjoint_native`), as ``operator.kernels`` says.

Everything a photon does before it first meets the printed top does not depend on the heights,
so it is traced once per operator (:meth:`NativeMeshTracer.prefix`): photons that never reach the
print add a fixed image and fixed losses, the others wait above the print with their state. Each
render or gradient then starts from those states. The gradient replays a chunk's events, keeping
each event's input state, and runs them backwards (:func:`operators.mesh.adjoint_native.retreat`) from
the splat's adjoint gather to the heights.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import torch

from operators.heightfield.surface import HeightFieldGrid
from operators.kernels.numba_settings import to_numpy
from operators.mesh import adjoint_native as ma
from operators.mesh import events_compiled
from operators.mesh import kernels_native as mk
from operators.mesh.culling import clear_faces
from operators.mesh.elements import PrintReachesElement
from operators.mesh.embree_native import EmbreeTriangles
from operators.mesh.locality import crossing_order
from operators.mesh.photon_chunks import PhotonChunk, Prefix, RenderBuffers, write_back
from operators.photon_operator import filter_radius_px
from operators.splat.splat import ImageAccumulator, PaddedAdjoint

__all__ = ["LOSSES", "NativeMeshTracer"]

# The kinds of lost flux a render reports (W each).
LOSSES = ("escaped", "max_depth", "inside_top", "fresnel_reflected", "missed_receiver")

# Event kinds, faces or planes and distances as the kernels take them.
_EVENT_DTYPES = (np.int64, np.int64, np.float64)
# Work continues on a compact copy of the photons under way once fewer than this share are.
COMPACT = 0.5
# A photon's splat arguments and status that a render keeps beside its events (bytes).
SPLAT_BYTES_PER_PHOTON = 6 * 8 + 8


def _numba_splat_arguments(state, status, sc, pos, metric, flux) -> float:
    """:func:`operators.mesh.kernels_native.splat_arguments`, returning the flux (W) of the landed
    photons beside the receiver as the C kernel does."""
    mk.splat_arguments(state, status, np.arange(len(state)), sc, pos, metric, flux)
    outside = (status == mk.LANDED) & (np.abs(state[:, mk.P:mk.P + 2]) > sc.receiver_half).any(1)
    return float(state[outside, mk.FLUX].sum())


class NativeMeshTracer:
    """Traces a :class:`operators.mesh.operator.MeshSceneOperator`'s photons natively."""

    def __init__(self, operator) -> None:
        self.operator = operator
        self.substrate = len(operator.elements)
        intersector = operator.intersector
        (self.face_element, self.v0, self.plane, self.dual, self.shading,
         self.neighbour) = intersector.face_arrays()
        self.indices = np.ascontiguousarray(operator.index_table.double().numpy())
        # Whether the C kernels trace (a chunk's photons through all their events per call), else numba
        # (one event of every photon per call).
        self.compiled = operator.settings.kernels == "c" and events_compiled.AVAILABLE
        self._dtype = torch.empty(0, dtype=operator.dtype).numpy().dtype  # the operator's dtype in numpy
        self._prefix: Prefix | None = None
        self._buffers = RenderBuffers()
        # The heights of the last render and its events per chunk, for a vjp at the same heights.
        self._events_seen: tuple[np.ndarray, list] | None = None
        # The last gradient's padded adjoint image and its border, overwritten by the next.
        self._padded: tuple[np.ndarray | None, int] | None = None
        # The same faces, in the same order, in an Embree scene that the kernels query.
        self._triangles = EmbreeTriangles(intersector.vertices, intersector.faces) if intersector.count else None
        self.embree = 0 if self._triangles is None else self._triangles.handle
        self.face_clear = (clear_faces(intersector.vertices, self.v0, self.plane) if intersector.count
                           else np.zeros(1, dtype=np.bool_))
        self._faces = (events_compiled.Faces(self.substrate, self.face_element, self.face_clear, self.indices, self.v0,
                                             self.plane, self.dual, self.shading, self.neighbour, self.embree)
                       if self.compiled else None)

    # -- scene constants ----------------------------------------------------------------------
    def constants(self, d: np.ndarray | None) -> mk.MeshConstants:
        """Kernel constants for heights ``d`` (m, m) (None: before the print, no hit search)."""
        op = self.operator
        scene, settings = op.scene, op.settings
        half, thickness = scene.substrate.half_width, scene.substrate.thickness
        zlo = zstart = zhi = thickness
        slope_x = slope_y = 0.0
        spacing = 1.0
        top_max = thickness
        if d is not None:
            grid = HeightFieldGrid(thickness, half, d.shape[0])
            zlo, zstart, zhi = grid.z_planes(d)
            slope_x, slope_y = grid.slope_bounds(d)
            spacing = grid.spacing
            top_max = thickness + float(d.max()) + 1e-9
        values = (half, thickness, spacing, zlo, zstart, zhi, slope_x, slope_y, top_max, op._lowest_element,
                  scene.receiver.z, settings.fresnel, op._to_pixels, scene.receiver.half_width,
                  filter_radius_px(settings.min_footprint_px, settings.pixel_integration), settings.max_pixel_radius)
        # One type per field whatever the config gave (20 or 20.0): numba compiles a kernel per signature.
        return mk.MeshConstants._make(bool(v) if name == "fresnel" else float(v)
                                      for name, v in zip(mk.MeshConstants._fields, values))

    # -- events -------------------------------------------------------------------------------
    def _trace(self, d: np.ndarray, chunk: PhotonChunk, sc: mk.MeshConstants, wait_at_top: bool,
               losses: dict[str, float], splat: events_compiled.SplatArguments | None = None,
               log: events_compiled.EventLog | None = None, replay: bool = False,
               start: np.ndarray | None = None) -> events_compiled.SplatArguments:
        """The chunk's photons through their events, by the C kernels (all events in one call) or
        by :meth:`_run` (the prefix's only: one event per call), and their splat arguments, which
        are returned (with the C kernels in ``splat``; None: new arrays); lost flux added to
        ``losses``; with the C kernels, each photon's events recorded into ``log`` or, with
        ``replay``, taken from it, and with ``start`` (N, STATE) the photons taken from there, their
        final states not kept."""
        if not self.compiled:
            self._run(d, chunk, sc, wait_at_top, losses)
            return self._splat_inputs(chunk, sc, losses)
        if splat is None:
            splat = events_compiled.SplatArguments.empty(len(chunk.state))
        final = None if start is not None else chunk.state
        lost = events_compiled.trace(d, final, chunk.medium, chunk.channel, chunk.status, chunk.events, chunk.clear,
                                     self.operator.settings.max_depth, wait_at_top, self._faces, sc, splat, log,
                                     replay, start)
        for kind, total in lost.items():
            losses[kind] += total
        return splat

    def _run(self, d: np.ndarray, chunk: PhotonChunk, sc: mk.MeshConstants, wait_at_top: bool, losses: dict[str, float],
             tape: list | None = None, events_log: list | None = None, events_replay: list | None = None) -> None:
        """Advance the chunk's photons until none is under way (or each has had max_depth
        events), adding lost flux to ``losses``. Once fewer than half of the photons worked on are
        under way, the work continues on a copy of those only (written back at the end). With
        ``tape``, each event's photons (indices into the chunk, None for all), input states,
        kinds, faces or planes and distances are appended for :meth:`_reverse`. Each event's kinds,
        faces or planes and distances are appended to ``events_log`` (compactly), or taken from
        ``events_replay`` (logged at the same heights) instead of searched for."""
        max_depth = self.operator.settings.max_depth
        work, index = chunk, None
        for event in range(max_depth):
            under_way = work.status == mk.UNDER_WAY
            count = int(under_way.sum())
            if count == 0:
                break
            if count < COMPACT * len(work.state):
                keep = np.flatnonzero(under_way)
                write_back(chunk, index, work)
                index = keep if index is None else index[keep]
                work = chunk.take(index)
            n = len(work.state)
            if events_replay is not None:
                kind, which, t = (a.astype(dtype) for a, dtype in zip(events_replay[event], _EVENT_DTYPES))
            else:
                kind, which, t = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n)
            fresnel = np.zeros(n)
            before = np.empty((n if tape is not None else 0, mk.STATE))
            mk.advance(d, work.state, work.medium, work.channel, work.status, work.clear,
                       event == 0 and not wait_at_top, self.embree, kind, which, t, events_replay is not None, fresnel,
                       before, wait_at_top, self.substrate, self.face_element, self.face_clear, self.indices, self.v0,
                       self.plane, self.dual, self.shading, self.neighbour, sc)
            work.events += (kind >= 0) & (kind != mk.AT_TOP)
            flux = work.state[:, mk.FLUX]
            losses["escaped"] += float(flux[kind == mk.ESCAPED].sum())
            losses["inside_top"] += float(flux[kind == mk.INSIDE_TOP].sum())
            losses["fresnel_reflected"] += float(fresnel.sum())
            if tape is not None:
                tape.append((index, before, kind, which, t))
            if events_log is not None:
                events_log.append((kind.astype(np.int8), which.astype(np.int32), t))
            done = (work.status == mk.UNDER_WAY) & (work.events >= max_depth)
            losses["max_depth"] += float(flux[done].sum())
            work.status[done] = mk.LOST
        write_back(chunk, index, work)

    def _reverse(self, d: np.ndarray, chunk: PhotonChunk, sc: mk.MeshConstants, tape: list, g_state: np.ndarray,
                 g_heights: np.ndarray) -> None:
        """Run a chunk's recorded events backwards: ``g_state`` (N, STATE), the gradient w.r.t.
        the photons' final states, into ``g_heights`` (threads, m, m)."""
        for index, before, kind, which, t in reversed(tape):
            g = g_state if index is None else g_state[index]
            channel = chunk.channel if index is None else chunk.channel[index]
            ma.retreat(d, before, kind, which, t, channel, self.substrate, self.face_element, self.indices, self.v0,
                       self.plane, self.dual, self.shading, sc, g, g_heights)
            if index is not None:
                g_state[index] = g

    def _splat_inputs(self, chunk: PhotonChunk, sc: mk.MeshConstants,
                      losses: dict[str, float] | None) -> events_compiled.SplatArguments:
        """The splat arguments of the chunk's photons from their final states, by the numba
        kernels; the flux landing beside the receiver is counted as missing it in ``losses``
        (None: not counted)."""
        splat = events_compiled.SplatArguments.empty(len(chunk.state))
        missed = _numba_splat_arguments(chunk.state, chunk.status, sc, splat.pos, splat.metric, splat.flux)
        if losses is not None:
            losses["missed_receiver"] += missed
        return splat

    def _image(self) -> ImageAccumulator:
        """An empty image (c, n, n) of the operator's dtype that chunks are splatted into."""
        scene = self.operator.scene
        return ImageAccumulator(scene.channels, scene.receiver.resolution, self._dtype, c_kernels=self.compiled)

    # -- the height-independent prefix --------------------------------------------------------
    def prefix(self) -> Prefix:
        """Trace every photon up to its first hit on the printed top (once per operator)."""
        if self._prefix is not None:
            return self._prefix
        op = self.operator
        sc = self.constants(None)
        dummy = np.zeros((4, 4))
        image = self._image()
        losses = dict.fromkeys(LOSSES, 0.0)
        waiting = []
        for start, stop in op.chunks():
            chunk = self._emitted(start, stop)
            splat = self._trace(dummy, chunk, sc, True, losses)
            image.add(splat.pos, splat.metric, splat.flux, chunk.channel)
            keep = chunk.status == mk.WAITING
            waiting.append((chunk.state[keep], chunk.channel[keep], chunk.events[keep]))
        state, channel, events = (np.concatenate(parts) for parts in zip(*waiting))
        size = op.settings.chunk_size
        order = crossing_order(state[:, mk.P:mk.P + 3], state[:, mk.W:mk.W + 3], op.scene.substrate.thickness, size)
        lowest = float(state[:, mk.P + 2].min()) if len(state) else math.inf
        self._prefix = Prefix(np.ascontiguousarray(state[order]), channel[order], events[order], image.image(), losses,
                              lowest)
        return self._prefix

    def _emitted(self, start: int, stop: int) -> PhotonChunk:
        """Photons start .. stop-1 at the light, as a chunk."""
        batch = self.operator.emitter.batch(start, stop)
        n = batch.direction.shape[1]
        state = np.zeros((n, mk.STATE))
        state[:, mk.P:mk.P + 3] = batch.origin.double().numpy()
        state[:, mk.W:mk.W + 3] = batch.direction.double().numpy().T
        state[:, mk.DWU:mk.DWU + 3] = batch.direction_diff[0].double().numpy().T
        state[:, mk.DWV:mk.DWV + 3] = batch.direction_diff[1].double().numpy().T
        state[:, mk.FLUX] = batch.flux.double().numpy()
        return PhotonChunk.starting(state, batch.channel.numpy().astype(np.int64), np.zeros(n, dtype=np.int64))

    def _waiting(self, start: int, stop: int, writable: bool = True) -> PhotonChunk:
        """Prefix photons start .. stop-1, about to meet the print, in the order they are traced
        in; their states and event counts are copies to trace in place, or with ``writable=False``
        views of the prefix (read only)."""
        pre = self.prefix()
        state, events = pre.state[start:stop], pre.events[start:stop]
        if writable:
            state, events = state.copy(), events.copy()
        return PhotonChunk.starting(state, pre.channel[start:stop], events)

    def _waiting_chunks(self) -> list[tuple[int, int]]:
        size, total = self.operator.settings.chunk_size, len(self.prefix().state)
        return [(a, min(a + size, total)) for a in range(0, total, size)]

    # -- render and gradient ------------------------------------------------------------------
    def render(self, d: np.ndarray) -> tuple[torch.Tensor, dict[str, float]]:
        """Flux per pixel (c, n, n) of heights ``d`` (m, m) float64 and the losses (W); the photons'
        events (with the C kernels: and their splat arguments) are kept for a :meth:`vjp` at the
        same heights, with the C kernels within ``event_log_mb``."""
        pre = self.prefix()
        sc = self.constants(d)
        self._check_above(sc)
        image = self._image()
        losses = dict(pre.losses)
        settings = self.operator.settings
        budget = settings.event_log_mb * 2 ** 20
        log_bytes = len(pre.state) * settings.max_depth * events_compiled.BYTES_PER_EVENT
        keep = not self.compiled or log_bytes <= budget
        keep_splat = self.compiled and log_bytes + len(pre.state) * SPLAT_BYTES_PER_PHOTON <= budget
        seen: list = []
        splats: list = []
        self._events_seen = None  # its arrays are the buffers this render refills
        for k, (start, stop) in enumerate(self._waiting_chunks()):
            chunk = self._waiting(start, stop, writable=not self.compiled)
            if self.compiled:
                chunk.events = chunk.events.copy()
                # The photons traced from the prefix, their splat arguments into a buffer of this
                # chunk (or, if not kept, of all).
                log = self._buffers.log(k, stop - start, settings.max_depth) if keep else None
                splat = self._trace(
                    d,
                    chunk,
                    sc,
                    False,
                    losses,
                    self._buffers.splat(k if keep_splat else 0, stop - start),
                    log,
                    start=chunk.state,
                )
                seen.append(log)
                if keep_splat:
                    splats.append((splat, chunk.status))
            else:
                seen.append([])
                self._run(d, chunk, sc, False, losses, events_log=seen[-1])
                splat = self._splat_inputs(chunk, sc, losses)
            image.add(splat.pos, splat.metric, splat.flux, chunk.channel)
        self._events_seen = (d.copy(), seen, splats if keep_splat else None) if keep else None
        return image.image().add_(pre.image), losses

    def vjp(self, d: np.ndarray, grad_flux: torch.Tensor) -> np.ndarray:
        """Gradient (m, m) w.r.t. d of <flux per pixel, grad_flux (c, n, n)>. The photons' events
        are replayed from the last :meth:`render` when it had the same heights (and kept them),
        else searched again; with the C kernels, the splat arguments that render kept spare the
        replay up to the splat. The C kernels take the gradient back through the logged events of
        packets of photons, event by event; the numba kernels keep a tape of every event's states and run it
        backwards."""
        sc = self.constants(d)
        self._check_above(sc)
        g_heights = np.zeros((nb.get_num_threads(), *d.shape))
        not_counted: dict[str, float] = dict.fromkeys(self.prefix().losses, 0.0)  # render counts them
        # Padded once for all chunks, into the buffer of the last gradient where it fits.
        adjoint = PaddedAdjoint(to_numpy(grad_flux), c_kernels=self.compiled, spare=self._padded)
        same = self._events_seen is not None and np.array_equal(self._events_seen[0], d)
        seen, splats = self._events_seen[1:] if same else (None, None)
        from_splats = self.compiled and splats is not None
        chunks = self._waiting_chunks()
        g_rows = None if self.compiled else np.empty((max((b - a for a, b in chunks), default=0), mk.STATE))
        for k, (start, stop) in enumerate(chunks):
            chunk = self._waiting(start, stop, writable=not self.compiled)
            if not self.compiled:
                tape: list = []
                self._run(d, chunk, sc, False, not_counted, tape, events_replay=None if seen is None else seen[k])
                splat = self._splat_inputs(chunk, sc, None)
                g_splat = adjoint.gather(splat.pos, splat.metric, splat.flux, chunk.channel)
                g_state = g_rows[:len(chunk.state)]
                ma.splat_arguments_adjoint(chunk.state, chunk.status, sc, *g_splat, g_state)
                self._reverse(d, chunk, sc, tape, g_state, g_heights)
                continue
            if from_splats:
                before, log = (chunk.state, chunk.medium, chunk.clear), seen[k]
                splat, status = splats[k]
            else:  # traced again from the prefix's states, which stay the reverse's start
                chunk.events = chunk.events.copy()
                before = (chunk.state, chunk.medium.copy(), chunk.clear.copy())
                log = (seen[k] if seen is not None
                       else events_compiled.EventLog.empty(len(chunk.state), self.operator.settings.max_depth))
                splat = self._trace(d, chunk, sc, False, not_counted, log=log, replay=seen is not None,
                                    start=chunk.state)
                status = chunk.status
            g_splat = adjoint.gather(splat.pos, splat.metric, splat.flux, chunk.channel)
            events_compiled.reverse(d, before, chunk.channel, status, log, self._faces, sc, g_splat, g_heights)
        self._padded = (adjoint.padded, adjoint.pad)
        return g_heights.sum(axis=0)

    def _check_above(self, sc: mk.MeshConstants) -> None:
        """Refuse a print that reaches photons waiting above it."""
        lowest = self.prefix().lowest
        if lowest <= sc.top_max:
            raise PrintReachesElement(f"the print reaches z={sc.top_max:.4g}, above where light meets it "
                             f"(z={lowest:.4g}); lower the print or move the elements up")
