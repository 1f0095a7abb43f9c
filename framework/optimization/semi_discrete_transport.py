"""Semi-discrete optimal transport from a density on a square to weighted points (pysdot).

The source is a piecewise-constant density on [lo, hi]^2 (an image, rows along y); the target is
a set of Dirac sites with masses. The optimal map for the quadratic cost sends the Laguerre
(power) cell of site i, {x : |x - y_i|^2 - w_i <= |x - y_j|^2 - w_j for all j}, to y_i; Newton's
method on the weights w (pysdot's power diagrams) makes every cell's source mass equal the site's
mass.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

__all__ = ["TransportPlan", "semi_discrete_transport"]

MAX_NEWTON_ROUNDS = 1000  # evaluations of the cells (steps and halvings) before Newton gives up (pysdot's cap)


@dataclass(frozen=True)
class TransportPlan:
    """The solved transport.

    Attributes:
        sites: (K, 2) target positions.
        masses: (K,) target masses (normalised to the source's total).
        centroids: (K, 2) barycentres of the sites' Laguerre cells in the source square.
        cell_masses: (K,) source mass of each cell.
        newton_steps: Newton iterations taken.
        weights: (K,) the Laguerre weights w_i.
        converged: whether every cell's mass reached its tolerance (False: stopped at the deadline).
    """

    sites: np.ndarray
    masses: np.ndarray
    centroids: np.ndarray
    cell_masses: np.ndarray
    newton_steps: int
    weights: np.ndarray
    converged: bool = True

    def site_of(self, points: np.ndarray, chunk: int = 4096) -> np.ndarray:
        """The site (N, 2) whose Laguerre cell holds each of ``points`` (N, 2): the semi-discrete
        map itself, argmin_i |x - y_i|^2 - w_i."""
        out = np.empty_like(points, dtype=np.float64)
        lifted = (self.sites ** 2).sum(axis=1) - self.weights
        for start in range(0, len(points), chunk):
            block = points[start:start + chunk]
            out[start:start + chunk] = self.sites[np.argmin(lifted[None, :] - 2.0 * block @ self.sites.T, axis=1)]
        return out

    @property
    def max_relative_mass_error(self) -> float:
        """max_i |cell mass_i - mass_i| / mass_i."""
        return float(np.max(np.abs(self.cell_masses - self.masses) / self.masses))


def semi_discrete_transport(density: np.ndarray, lo: float, hi: float, sites: np.ndarray, masses: np.ndarray,
                            tolerance: float = 1e-3, deadline: float | None = None) -> TransportPlan:
    """Transport ``density`` (H, W) >= 0 on [lo, hi]^2 onto ``sites`` (K, 2) with ``masses`` (K,) > 0.

    The masses are scaled to the density's total. Newton stops when every cell's mass is within
    ``tolerance`` times the smallest site mass of its target, or at ``deadline`` (a
    ``time.perf_counter()`` value; None: none) with the weights of its last step
    (``converged=False``).
    """
    from pysdot import OptimalTransport
    from pysdot.domain_types import ScaledImage

    density = np.ascontiguousarray(density, dtype=np.float64)
    sites = np.ascontiguousarray(sites, dtype=np.float64)
    masses = np.asarray(masses, dtype=np.float64)
    if density.ndim != 2 or np.any(density < 0) or not np.all(np.isfinite(density)) or density.sum() <= 0:
        raise ValueError("the source density must be a finite, non-negative (H, W) image with some light")
    if sites.ndim != 2 or sites.shape[1] != 2 or len(sites) != len(masses) or len(sites) == 0:
        raise ValueError(f"need (K, 2) sites and K masses, K >= 1; got {sites.shape} and {masses.shape}")
    if np.any(masses <= 0) or not np.all(np.isfinite(masses)):
        raise ValueError("site masses must be finite and positive (leave black pixels out)")
    if np.any(sites < lo) or np.any(sites > hi):
        raise ValueError(f"sites must lie in the source square [{lo}, {hi}]^2")
    # A floor of 1e-6 of the mean light: a site over a dark part of the source (the unlit rim of a
    # flat caustic) then starts with a tiny but non-empty Voronoi cell instead of stopping Newton.
    density = density + 1e-6 * density.mean()
    domain = ScaledImage([lo, lo], [hi, hi], density)
    masses = masses * (domain.measure() / masses.sum())
    transport = OptimalTransport(sites, domain=domain, masses=masses, linear_solver="Scipy")
    transport.set_weights(np.zeros(len(sites)))  # Voronoi cells: none is empty
    steps, converged = _newton(transport, masses, tolerance * float(masses.min()), deadline)
    cell_masses = np.asarray(transport.pd.integrals(), dtype=np.float64)
    return TransportPlan(sites, masses, np.asarray(transport.get_centroids(), dtype=np.float64), cell_masses,
                         steps, np.asarray(transport.get_weights(), dtype=np.float64), converged)


def _newton(transport: object, masses: np.ndarray, max_mass_error: float, deadline: float | None) -> tuple[int, bool]:
    """Newton on ``transport``'s Laguerre weights until every cell's mass is within
    ``max_mass_error`` of ``masses``, the clock passes ``deadline`` or :data:`MAX_NEWTON_ROUNDS`
    evaluations are spent. A step that empties a cell is halved back toward the last weights
    without one (pysdot's rule). Returns (steps taken, converged)."""
    diagram = transport.pd  # type: ignore[attr-defined]
    solver = transport._get_linear_solver()  # type: ignore[attr-defined]  # pysdot's own (scipy) sparse solver
    good = diagram.get_weights().copy()
    steps = 0
    for rounds in range(MAX_NEWTON_ROUNDS):
        derivatives = diagram.der_integrals_wrt_weights(stop_if_void=True)
        late = rounds == MAX_NEWTON_ROUNDS - 1 or (deadline is not None and time.perf_counter() >= deadline)
        if derivatives.error:  # an empty cell
            if steps == 0:
                raise ValueError("a Laguerre cell is empty at zero weights: a site lies outside the source's light")
            if late:
                diagram.set_weights(good)
                return steps, False
            diagram.set_weights(0.5 * (good + diagram.get_weights()))
            continue
        good = diagram.get_weights().copy()
        residual = derivatives.v_values - masses
        if float(np.max(np.abs(residual))) < max_mass_error:
            return steps, True
        if late:
            return steps, False
        values = derivatives.m_values
        values[0] *= 2.0  # the weights are free up to a constant: a stiffer first cell fixes it (as pysdot does)
        matrix = solver.create_matrix(len(masses), derivatives.m_offsets, derivatives.m_columns, values)
        diagram.set_weights(good - solver.solve(matrix, solver.create_vector(residual)))
        steps += 1
    raise AssertionError("unreachable: the last round returns")
