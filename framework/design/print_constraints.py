"""What a printer or a mill can make: the limits a caustic design keeps (docs/design.md, "Printability").

Heights d (m, m) in scene units at linspace(-W, W, m), spacing h = 2 W / (m - 1). The limits:

- heights: 0 <= d <= ``max_height`` (and d = 0 outside ``mask``, where nothing is printed);
- slope: the gradient of every grid cell (the mean of its two forward differences along x and
  along y) has length <= ``max_slope``;
- feature size: every crest and valley along x and y has a radius of curvature >= ``min_feature`` / 2,
  i.e. |second difference| / h^2 <= 2 / ``min_feature`` (a ball of that diameter, the tool or the
  deposition bead, follows the surface);
- volume: sum(d) h^2 = ``volume`` (optional).

All are convex, so the nearest printable design is a convex projection: :meth:`PrintConstraints.project`
solves it by ADMM and then makes it hold to rounding by pulling the result toward a design that
keeps every limit strictly (flat glass, or a flat layer of the volume).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import torch
from scipy.sparse.linalg import factorized

from framework.core.problem import Problem
from operators.values import checked_number

__all__ = ["DesignProblem", "PrintConstraints", "printing_limits"]

ADMM_RHO = 16.0  # the splitting's penalty (docs/design.md, "Printability": nearer and faster than 1 at 256 x 256)
ADMM_ITERATIONS = 400
ADMM_TOLERANCE = 1e-6  # primal and dual residuals over |x| at which ADMM stops; the pull inside makes limits exact


def _difference(m: int) -> sp.csr_matrix:
    return sp.diags([-np.ones(m - 1), np.ones(m - 1)], [0, 1], shape=(m - 1, m), format="csr")


def _operators(m: int) -> tuple[sp.csr_matrix, sp.csr_matrix, sp.csr_matrix]:
    """(Gx, Gy, C) on d.ravel() (rows along y), in height units (not divided by h): the cells'
    mean forward differences along x and y ((m-1)^2 each) and the second differences along x and
    along y at interior samples (2 m (m-2))."""
    diff = _difference(m)
    mean = sp.diags([0.5 * np.ones(m - 1), 0.5 * np.ones(m - 1)], [0, 1], shape=(m - 1, m), format="csr")
    gx, gy = sp.kron(mean, diff, format="csr"), sp.kron(diff, mean, format="csr")
    second = sp.diags([np.ones(m - 2), -2 * np.ones(m - 2), np.ones(m - 2)], [0, 1, 2], shape=(m - 2, m))
    eye = sp.identity(m, format="csr")
    return gx, gy, sp.vstack([sp.kron(eye, second), sp.kron(second, eye)], format="csr")


@dataclass(frozen=True)
class PrintConstraints:
    """The printing limits of a design on an (m, m) grid of spacing ``spacing`` (scene units).

    Attributes:
        max_height: Highest print, scene units (> 0).
        max_slope: Steepest cell gradient (dimensionless, > 0).
        min_feature: Smallest crest or valley diameter, scene units (None: no limit).
        volume: The print's volume, scene units^3 (None: free).
        mask: (m, m) bool, where printing is allowed (None: everywhere).
        spacing: h, scene units.
    """

    max_height: float
    max_slope: float
    min_feature: float | None
    volume: float | None
    mask: np.ndarray | None
    spacing: float

    def __post_init__(self) -> None:
        for name in ("max_height", "max_slope", "spacing"):
            checked_number(getattr(self, name), f"constraints.{name}", above=0.0, must="must be a number > 0")
        for name in ("min_feature", "volume"):
            if getattr(self, name) is not None:
                checked_number(getattr(self, name), f"constraints.{name}", above=0.0,
                               must="must be a number > 0 or null")

    @property
    def max_curvature(self) -> float:
        """2 / min_feature (1 / scene unit), inf without a feature size."""
        return math.inf if self.min_feature is None else 2.0 / self.min_feature

    def _allowed(self, shape: tuple[int, ...]) -> np.ndarray:
        return np.ones(shape, dtype=bool) if self.mask is None else np.asarray(self.mask, dtype=bool)

    def check_grid(self, m: int) -> None:
        """Refuse limits no design on an (m, m) grid can keep (a volume above the highest print
        everywhere, a mask of another shape)."""
        if self.mask is not None and np.shape(self.mask) != (m, m):
            raise ValueError(f"constraints.mask has shape {np.shape(self.mask)}; the height field is ({m}, {m})")
        if self.volume is not None:
            most = float(self._allowed((m, m)).sum()) * self.max_height * self.spacing ** 2
            if self.volume > most:
                raise ValueError(f"constraints.volume={self.volume:.4g} exceeds the {most:.4g} that max_height "
                                 "fills over the printable area; lower the volume or raise constraints.max_height")

    # -- measuring ---------------------------------------------------------------------------------
    def measure(self, d: np.ndarray) -> dict[str, float]:
        """The design's figures against each limit: max/min height, steepest slope, largest
        curvature (1 / scene unit), volume (scene units^3), highest sample outside the mask."""
        d = np.asarray(d, dtype=np.float64)
        h = self.spacing
        gx = 0.5 * ((d[:-1, 1:] - d[:-1, :-1]) + (d[1:, 1:] - d[1:, :-1])) / h
        gy = 0.5 * ((d[1:, :-1] - d[:-1, :-1]) + (d[1:, 1:] - d[:-1, 1:])) / h
        cx = np.abs(d[:, 2:] - 2 * d[:, 1:-1] + d[:, :-2]) / h ** 2
        cy = np.abs(d[2:, :] - 2 * d[1:-1, :] + d[:-2, :]) / h ** 2
        outside = d[~self._allowed(d.shape)]
        return {
            "max_height": float(d.max()),
            "min_height": float(d.min()),
            "max_slope": float(np.hypot(gx, gy).max()),
            "max_curvature": float(max(cx.max(), cy.max())),
            "volume": float(d.sum()) * h**2,
            "outside_mask": float(np.abs(outside).max()) if outside.size else 0.0,
        }

    def holds(self, d: np.ndarray, rtol: float = 1e-9) -> dict[str, bool]:
        """Whether each limit holds, to ``rtol`` of its value (rounding)."""
        f = self.measure(d)
        out = {
            "heights": f["min_height"] >= -rtol * self.max_height and f["max_height"] <= self.max_height * (1 + rtol),
            "slope": f["max_slope"] <= self.max_slope * (1 + rtol),
            "feature_size": f["max_curvature"] <= self.max_curvature * (1 + rtol),
            "mask": f["outside_mask"] <= rtol * self.max_height,
        }
        if self.volume is not None:
            out["volume"] = abs(f["volume"] - self.volume) <= 1e-6 * self.volume
        return out

    # -- a soft version for the optimisers -----------------------------------------------------------
    def penalty(self, d: torch.Tensor) -> torch.Tensor:
        """Sum over samples / cells of the squared violations, each relative to its limit
        (differentiable; 0 where every limit holds); the volume's relative miss squared."""
        h = self.spacing
        terms = [torch.relu(d - self.max_height) / self.max_height, torch.relu(-d) / self.max_height]
        gx = 0.5 * ((d[:-1, 1:] - d[:-1, :-1]) + (d[1:, 1:] - d[1:, :-1])) / h
        gy = 0.5 * ((d[1:, :-1] - d[:-1, :-1]) + (d[1:, 1:] - d[:-1, 1:])) / h
        slope = torch.sqrt(gx ** 2 + gy ** 2 + (1e-6 * self.max_slope) ** 2)
        terms.append(torch.relu(slope - self.max_slope) / self.max_slope)
        if self.min_feature is not None:
            limit = self.max_curvature * h ** 2
            terms += [torch.relu((d[:, 2:] - 2 * d[:, 1:-1] + d[:, :-2]).abs() - limit) / limit,
                      torch.relu((d[2:, :] - 2 * d[1:-1, :] + d[:-2, :]).abs() - limit) / limit]
        if self.mask is not None:
            outside = ~torch.as_tensor(self.mask, dtype=torch.bool, device=d.device)
            terms.append(d[outside] / self.max_height)
        total = sum(((t ** 2).sum() for t in terms), d.new_zeros(()))
        if self.volume is not None:
            total = total + ((d.sum() * h ** 2 - self.volume) / self.volume) ** 2 * d.numel()
        return total

    # -- the exact projection -------------------------------------------------------------------------
    def project(self, d: np.ndarray) -> np.ndarray:
        """The printable design nearest to ``d`` (m, m) in the L2 sense (ADMM), then made to hold
        to rounding (:meth:`holds`) by the smallest pull toward a strictly printable reference."""
        d0 = np.asarray(d, dtype=np.float64)
        m = d0.shape[0]
        self.check_grid(m)
        allowed = self._allowed(d0.shape).ravel()
        h = self.spacing
        gx, gy, curvature = _operators(m)
        slope_limit, curvature_limit = self.max_slope * h, self.max_curvature * h ** 2
        blocks = [gx, gy] + ([curvature] if self.min_feature is not None else [])
        stack = sp.vstack(blocks + [sp.identity(m * m, format="csr")], format="csr")
        rho = ADMM_RHO
        solve = factorized((sp.identity(m * m) + rho * (stack.T @ stack)).tocsc())
        ones = np.ones(m * m)
        a_ones = solve(ones) if self.volume is not None else None
        target_sum = None if self.volume is None else self.volume / h ** 2
        cells = gx.shape[0]
        x = d0.ravel().copy()
        z = stack @ x
        u = np.zeros_like(z)
        for _ in range(ADMM_ITERATIONS):
            x = solve(d0.ravel() + rho * (stack.T @ (z - u)))
            if a_ones is not None:
                x = x + a_ones * (target_sum - x.sum()) / a_ones.sum()
            v = stack @ x + u
            z_new = v.copy()
            g = np.hypot(v[:cells], v[cells:2 * cells])
            shrink = np.minimum(1.0, slope_limit / np.maximum(g, 1e-300))
            z_new[:cells] *= shrink
            z_new[cells:2 * cells] *= shrink
            end = 2 * cells
            if self.min_feature is not None:
                end += curvature.shape[0]
                z_new[2 * cells:end] = np.clip(v[2 * cells:end], -curvature_limit, curvature_limit)
            z_new[end:] = np.where(allowed, np.clip(v[end:], 0.0, self.max_height), 0.0)
            primal = np.linalg.norm(stack @ x - z_new)
            dual = rho * np.linalg.norm(stack.T @ (z_new - z))
            u = v - z_new
            z = z_new
            if max(primal, dual) <= ADMM_TOLERANCE * max(float(np.linalg.norm(x)), 1e-300):
                break
        return self._pulled_inside(x.reshape(m, m), allowed.reshape(m, m))

    def _pulled_inside(self, d: np.ndarray, allowed: np.ndarray) -> np.ndarray:
        """reference + lam (d - reference) with the largest lam in [0, 1] that keeps every limit:
        slopes and curvatures scale with lam, the volume of d and of the reference agree."""
        if self.volume is None:
            reference = np.zeros_like(d)
            d = np.where(allowed, np.clip(d, 0.0, None), 0.0)
        elif self.mask is None or allowed.all():
            reference = np.full_like(d, self.volume / (self.spacing ** 2 * d.size))
        else:  # no flat reference keeps both the mask and the volume: ADMM's result, clipped
            return np.where(allowed, np.clip(d, 0.0, self.max_height), 0.0)
        f = self.measure(d)
        lam = 1.0
        if f["max_slope"] > self.max_slope:
            lam = min(lam, self.max_slope / f["max_slope"])
        if f["max_curvature"] > self.max_curvature:
            lam = min(lam, self.max_curvature / f["max_curvature"])
        top, bottom = float(reference.max()), float(reference.min())
        if f["max_height"] > self.max_height:
            lam = min(lam, (self.max_height - top) / (f["max_height"] - top))
        if f["min_height"] < 0.0:
            lam = min(lam, bottom / (bottom - f["min_height"]))
        lam *= 1.0 - 1e-12
        return reference + lam * (d - reference)


@dataclass(frozen=True)
class DesignProblem(Problem):
    """A caustic-design problem: a :class:`framework.core.problem.Problem` with the printing limits
    its design solvers keep (framework/design/design_refinement.py)."""

    constraints: PrintConstraints | None = None


def printing_limits(problem: Problem) -> PrintConstraints | None:
    """A design problem's printing limits; None for a problem without them (a reconstruction)."""
    return problem.constraints if isinstance(problem, DesignProblem) else None
