"""Caustic design after Schwartzburg et al. 2014 ("High-contrast computational caustic design"), as
a baseline for reconstruction (the paper's Fig. 6): the plugin ``solver/schwartzburg``.

It designs a top surface whose caustic is the target image, knowing nothing of the print (no mask,
bounds or volume):

1. Optimal transport (:mod:`.semi_discrete_transport`) of the light that reaches the receiver
   through flat glass (the operator's render of d = 0: the point light's falloff, the slab's
   refraction, the footprint blur and the light lost past the receiver's edge, all from our own
   scene) onto the target image: the target's lit pixels are Dirac sites, the flat-glass caustic a
   piecewise-constant density, both on the receiver. Each pixel's Laguerre cell collects the
   light that flat glass would put there and sends it to the pixel; the cells' centroids and
   their pixels, interpolated linearly at the height samples' flat-glass landing points (the
   paraxial magnification k of :func:`flat_magnification`), give every height sample its target
   point T_j. The flat-glass caustic as the source (``source: flat_caustic``) makes flat glass the
   design of its own caustic. ``source: light_on_glass`` takes the literal source instead, the
   point light's irradiance (z_L - h) / r^3 on the substrate top, scaled by k onto the receiver:
   its rim does not match a target's blurred, clipped rim, and for the flat-glass caustic itself
   it designs a lens 0.12 high (rel. discrepancy 0.035, 32 x 32 heights, 64 x 64 receiver).
2. Snell: the direction inside the glass that leaves the flat bottom toward T_j
   (:func:`operators.optics.inverse_refraction.glass_directions`) and the top normal that refracts the
   light into it (:func:`operators.optics.inverse_refraction.snell_normals`), i.e. the slopes
   (d_x, d_y) = -(N_x, N_y) / N_z.
3. The surface: heights whose finite-difference slopes match those (least squares on the grid's
   edges) plus ``smoothness`` times the squared Laplacian (per cell), solved exactly (one sparse
   factorisation); then, as the surface moved, the incident directions and the in-glass paths are
   recomputed from the new heights and the fit is repeated, until the heights change by less than
   ``outer_tolerance`` (relative) between two outer iterations.

The heights are fixed up to a constant by the slopes; the design is taken to sit on the substrate:
its lowest sample at d = 0. Each outer iteration is one iteration of the solver loop (the first
also solves the transport), with the discrepancy of the design rendered through the problem's
operator (where the problem has printing limits, of the design clipped to its height limits: a fit
taller than them may reach into an optical element above the glass, which no operator renders)
and the residual normal error (RMS angle between the fitted surface's normals and the
required ones) among its metrics.
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp
import torch
from scipy.interpolate import griddata
from scipy.sparse.linalg import factorized
from torch import Tensor

from framework.core.solver_loop import IterationFailed, IterationRecord, IterativeSolver
from framework.optimization.semi_discrete_transport import TransportPlan, semi_discrete_transport
from framework.design.print_constraints import printing_limits
from operators.optics.inverse_refraction import flat_magnification, glass_directions, snell_normals
from operators.values import checked_number

if TYPE_CHECKING:
    from framework.core.problem import Problem

__all__ = ["SchwartzburgDesign", "SOURCES", "flat_magnification", "light_on_glass", "slope_fit_system"]

SOURCES = ("flat_caustic", "light_on_glass")
OUTSIDE_HULL = ("flat", "cell", "auto")
# outside_hull=auto sends the samples outside the centroids' hull to their cells' pixels when the hull
# holds less than this share of the samples (a 2 x 2-pixel spot on a 32 px screen: 25%; the built-in targets
# on sfc-design's 128 px transport screen: 98%).
AUTO_CELL_BELOW = 0.5


def light_on_glass(light: tuple[float, float, float], thickness: float, half_width: float, resolution: int
                   ) -> np.ndarray:
    """Irradiance (resolution, resolution) of the point light on the plane z = thickness over
    [-W, W]^2 at cell centres, rows along y: (z_L - h) / r^3 (up to the light's power)."""
    centres = (np.arange(resolution) + 0.5) / resolution * 2 * half_width - half_width
    x, y = np.meshgrid(centres - light[0], centres - light[1])
    height = light[2] - thickness
    return height / (x ** 2 + y ** 2 + height ** 2) ** 1.5


def slope_fit_system(m: int, spacing: float, smoothness: float) -> tuple[sp.csr_matrix, sp.csr_matrix, Any]:
    """(Dx, Dy, solve): forward differences per edge along x (columns) and y (rows) of an (m, m)
    grid, in slope units, and the factorised normal equations of
    min_d |Dx d - gx|^2 + |Dy d - gy|^2 + smoothness |spacing L d|^2 + d_00^2,
    L the 5-point Laplacian with reflecting borders; the last term fixes the free constant."""
    eye = sp.identity(m, format="csr")
    diff = sp.diags([-np.ones(m - 1), np.ones(m - 1)], [0, 1], shape=(m - 1, m)) / spacing
    dx, dy = sp.kron(eye, diff, format="csr"), sp.kron(diff, eye, format="csr")
    second = (diff.T @ diff) * spacing  # (m, m), 1-D Laplacian with reflecting ends, per cell
    laplacian = sp.kron(eye, second) + sp.kron(second, eye)
    pin = sp.csr_matrix(([1.0], ([0], [0])), shape=(m * m, m * m))
    system = dx.T @ dx + dy.T @ dy + smoothness * (laplacian.T @ laplacian) + pin
    return dx, dy, factorized(system.tocsc())


class SchwartzburgDesign(IterativeSolver):
    """Schwartzburg-style caustic design on the problem's scene (see the module docstring).

    Args:
        problem: The reconstruction problem (its target, scene and grid; its mask, bounds and volume
            are not used).
        d0: Start heights (m, m); the design starts its surface there.
        mass_tolerance: Newton stops when every Laguerre cell's mass is within this fraction of the
            smallest pixel mass of its pixel's mass.
        black_level: Pixels below this fraction of the brightest pixel are black (no site; noise
            below zero is black too).
        smoothness: Weight of the squared Laplacian against the slope misfit (dimensionless).
        outer_tolerance: Stop when ||d_k - d_{k-1}|| <= outer_tolerance ||d_k||.
        power_tolerance: Refuse a target whose power differs from what flat glass puts on the
            receiver by more than this fraction (a refractive surface only moves light).
        source: ``flat_caustic`` or ``light_on_glass``, the transport's source (module docstring).
        outside_hull: Where samples outside the hull of the cells' centroids send their light:
            ``flat`` (where flat glass does), ``cell`` (their Laguerre cell's pixel) or ``auto``
            (``cell`` where the hull holds less than :data:`AUTO_CELL_BELOW` of the samples, a
            target of a few pixels whose light the hull cannot gather, else ``flat``).
    """

    name = "schwartzburg"

    def __init__(self, problem: Problem, d0: Tensor, mass_tolerance: float = 1e-3, black_level: float = 1e-3,
                 smoothness: float = 0.1, outer_tolerance: float = 1e-2, power_tolerance: float = 0.1,
                 source: str = "flat_caustic", outside_hull: str = "flat") -> None:
        super().__init__(d0)
        if outside_hull not in OUTSIDE_HULL:
            raise ValueError(f"outside_hull={outside_hull!r} must be one of {', '.join(OUTSIDE_HULL)}")
        self.outside_hull = outside_hull
        self.problem = problem
        self.settings = self.checked_settings(mass_tolerance, black_level, smoothness, outer_tolerance, power_tolerance,
                                              source)
        scene, grid = problem.scene, problem.grid
        self.index = float(np.mean(scene.indices))
        coords = np.linspace(-grid.half_width, grid.half_width, grid.resolution)
        self._x, self._y = np.meshgrid(coords, coords)
        self._dx, self._dy, self._solve = slope_fit_system(grid.resolution, coords[1] - coords[0], smoothness)
        self._scale = flat_magnification(scene.light.position[2], grid.base, self.index, scene.receiver.z)
        self.targets: np.ndarray | None = None  # (m, m, 2) receiver point of every height sample
        self._change = math.inf

    @staticmethod
    def checked_settings(mass_tolerance: float, black_level: float, smoothness: float, outer_tolerance: float,
                         power_tolerance: float, source: str) -> dict[str, Any]:
        """The settings, each checked (a ValueError names the bad one)."""
        for name, value, low, high in (
            ("mass_tolerance", mass_tolerance, 0.0, 1.0),
            ("black_level", black_level, 0.0, 1.0),
            ("outer_tolerance", outer_tolerance, 0.0, 1.0),
            ("power_tolerance", power_tolerance, 0.0, 1.0),
        ):
            checked_number(value, f"solver.{name}", above=low, below=high, must=f"must lie in ({low}, {high})")
        if source not in SOURCES:
            raise ValueError(f"solver.source={source!r}; use {' or '.join(SOURCES)}")
        checked_number(smoothness, "solver.smoothness", 0.0)
        return {"mass_tolerance": float(mass_tolerance), "black_level": float(black_level),
                "smoothness": float(smoothness), "outer_tolerance": float(outer_tolerance),
                "power_tolerance": float(power_tolerance), "source": source}

    @classmethod
    def from_config(cls, mass_tolerance: float = 1e-3, black_level: float = 1e-3, smoothness: float = 0.1,
                    outer_tolerance: float = 1e-2, power_tolerance: float = 0.1, source: str = "flat_caustic",
                    outside_hull: str = "flat") -> Any:
        """The plugin ``solver/schwartzburg``: checks the settings, returns the builder."""
        settings = cls.checked_settings(mass_tolerance, black_level, smoothness, outer_tolerance, power_tolerance,
                                        source)
        if outside_hull not in OUTSIDE_HULL:
            raise ValueError(f"solver.outside_hull={outside_hull!r} must be one of {', '.join(OUTSIDE_HULL)}")
        return lambda problem, d0: cls(problem, d0, **settings, outside_hull=outside_hull)

    # -- the three stages ----------------------------------------------------------------------
    def transport(self) -> TransportPlan:
        """Stage 1: the transport of the source (the flat-glass caustic, or the light on the glass
        scaled onto the receiver) onto the target's lit pixels, in receiver coordinates; its Newton
        stops at the solver's ``deadline`` if that comes first (the plan then says
        ``converged=False``)."""
        scene, grid, operator = self.problem.scene, self.problem.grid, self.problem.operator
        image = self.problem.data.target.detach().double().sum(dim=0).cpu().numpy()
        if not np.isfinite(image).all() or image.max() <= 0.0:
            raise ValueError("the target caustic has no light (no pixel above 0); a design needs a lit target")
        flat = operator.render(torch.zeros(grid.shape, dtype=operator.dtype)).detach().double().sum(dim=0).cpu().numpy()
        ratio = float(image.sum()) / float(flat.sum())
        if abs(ratio - 1.0) > self.settings["power_tolerance"]:
            raise ValueError(f"the target caustic carries {ratio:.1%} of the power that flat glass puts on the "
                             "receiver; a refractive design only moves light: scale the image (data.brightness=energy)"
                             " or raise solver.power_tolerance")
        n, half = image.shape[-1], scene.receiver.half_width
        centres = (np.arange(n) + 0.5) / n * 2 * half - half
        rx, ry = np.meshgrid(centres, centres)
        lit = image > self.settings["black_level"] * image.max()
        sites = np.stack([rx[lit], ry[lit]], axis=1)
        if self.settings["source"] == "flat_caustic":
            return semi_discrete_transport(np.clip(flat, 0.0, None), -half, half, sites, image[lit],
                                           self.settings["mass_tolerance"], self.deadline)
        light = light_on_glass(scene.light.position, grid.base, grid.half_width, 2 * n)
        reach = grid.half_width * self._scale
        if reach < half:
            raise ValueError(f"the substrate's shadow (half width {reach:.3g}) does not cover the receiver "
                             f"({half:.3g}); use solver.source=flat_caustic")
        return semi_discrete_transport(light, -reach, reach, sites, image[lit], self.settings["mass_tolerance"],
                                       self.deadline)

    def _target_points(self, plan: TransportPlan) -> np.ndarray:
        """Every height sample's receiver point (m, m, 2): the map centroid -> pixel at the sample's
        flat-glass landing point, linear between centroids; outside their hull flat glass's landing
        point, or with ``outside_hull="cell"`` (``auto`` for a hull of few samples) on the receiver
        the pixel of the Laguerre cell that holds it (the transport map itself: a focus of few pixels
        gathers all the light)."""
        landing = np.stack([self._x, self._y], axis=-1) * self._scale
        points = (landing[..., 0], landing[..., 1])
        out = np.stack([griddata(plan.centroids, plan.sites[:, k], points, method="linear") for k in range(2)], axis=-1)
        within = float(np.isfinite(out[..., 0]).mean())
        if self.outside_hull == "flat" or (self.outside_hull == "auto" and within >= AUTO_CELL_BELOW):
            return np.where(np.isfinite(out), out, landing)
        cell = plan.site_of(landing.reshape(-1, 2)).reshape(landing.shape)
        on_receiver = (np.abs(landing) <= self.problem.scene.receiver.half_width).all(axis=-1, keepdims=True)
        return np.where(np.isfinite(out), out, np.where(on_receiver, cell, landing))

    def required_normals(self, d: np.ndarray) -> np.ndarray:
        """Stage 2: unit normals (m, m, 3) that send the light through each sample of the surface
        h + d to its target point."""
        scene = self.problem.scene
        points = np.stack([self._x, self._y, self.problem.grid.base + d], axis=-1).reshape(-1, 3)
        incident = points - np.asarray(scene.light.position)
        incident /= np.linalg.norm(incident, axis=1, keepdims=True)
        inside = glass_directions(points, self.targets.reshape(-1, 2), self.index, scene.receiver.z)
        return snell_normals(incident, inside, self.index).reshape(*d.shape, 3)

    def fit_surface(self, normals: np.ndarray) -> np.ndarray:
        """Stage 3: heights (m, m) whose slopes fit the normals' best, lowest sample at 0."""
        gx, gy = -normals[..., 0] / normals[..., 2], -normals[..., 1] / normals[..., 2]
        edge_x = 0.5 * (gx[:, 1:] + gx[:, :-1]).ravel()
        edge_y = 0.5 * (gy[1:, :] + gy[:-1, :]).ravel()
        d = self._solve(self._dx.T @ edge_x + self._dy.T @ edge_y).reshape(gx.shape)
        return d - d.min()

    @staticmethod
    def normal_error_deg(d: np.ndarray, normals: np.ndarray, spacing: float) -> float:
        """RMS angle (degrees) between the normals of the surface d and ``normals`` (m, m, 3)."""
        gy, gx = np.gradient(d, spacing)
        surface = np.stack([-gx, -gy, np.ones_like(d)], axis=-1)
        surface /= np.linalg.norm(surface, axis=-1, keepdims=True)
        cosine = np.clip((surface * normals).sum(axis=-1), -1.0, 1.0)
        return float(np.degrees(np.sqrt(np.mean(np.arccos(cosine) ** 2))))

    # -- the solver loop -----------------------------------------------------------------------
    def step(self) -> IterationRecord:
        """One outer iteration (the first also solves the transport)."""
        t0 = time.perf_counter()
        extras: dict[str, float] = {}
        if self.targets is None:
            plan = self.transport()
            self.targets = self._target_points(plan)
            extras = {"transport_sites": float(len(plan.sites)), "transport_newton_steps": float(plan.newton_steps),
                      "transport_max_relative_mass_error": plan.max_relative_mass_error,
                      "transport_converged": float(plan.converged),
                      "transport_seconds": time.perf_counter() - t0}
        d_old = self.state.d.detach().cpu().double().numpy()
        normals = self.required_normals(d_old)
        d_new = self.fit_surface(normals)
        if not np.isfinite(d_new).all():
            raise IterationFailed("the surface fit produced non-finite heights")
        spacing = float(self._x[0, 1] - self._x[0, 0])
        extras["normal_error_deg"] = self.normal_error_deg(d_new, self.required_normals(d_new), spacing)
        self._change = float(np.linalg.norm(d_new - d_old) / max(np.linalg.norm(d_new), 1e-300))
        extras["relative_change"] = self._change
        self.state.d = torch.from_numpy(d_new).to(self.state.d)
        limits = printing_limits(self.problem)
        printed = self.state.d if limits is None else self.state.d.clamp(0.0, limits.max_height)
        evaluation = self.problem.fidelity.evaluate(printed, with_grad=False)
        self.state.iteration += 1
        self.state.elapsed_s += time.perf_counter() - t0
        record = IterationRecord(self.state.iteration, evaluation.value, evaluation.value, evaluation.rel_discrepancy,
                                 0.0, self.state.elapsed_s, extras)
        self.history.append(record)
        return record

    def finished(self) -> str | None:
        """Done when an outer iteration changed the heights by less than ``outer_tolerance``."""
        if self._change <= self.settings["outer_tolerance"]:
            return f"the design's heights changed by {self._change:.2g} <= {self.settings['outer_tolerance']:g}"
        return None

    def state_dict(self) -> dict[str, Any]:
        """Adds the target points of the transport and the last change."""
        targets = None if self.targets is None else torch.from_numpy(self.targets)
        return {**super().state_dict(), "targets": targets, "change": self._change}

    def load_state_dict(self, state: dict[str, Any]) -> None:  # noqa: D102
        super().load_state_dict(state)
        self.targets = None if state.get("targets") is None else state["targets"].numpy()
        self._change = float(state.get("change", math.inf))
