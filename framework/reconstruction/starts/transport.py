"""The masked transport start (plugin ``initial/transport``): heights whose refraction moves the
light of the printed region onto the measured caustic (docs/method.md, "The start").

Only the printed region N^ (the mask) bends light; light through the bare glass beside it lands
where flat glass puts it. So, on the receiver:

1. Source: the flat-glass caustic of the masked region alone, S = F(0) r, where r is the share
   of each pixel's flat-glass light that came through the mask (the operator's photons traced
   through flat glass: where they meet the top, the operator's ``arrivals``, and where they land,
   its ``land_from_bottom``, operators/image_operator.py).
2. Goal: the measured caustic minus the bare region's light, G = max(b - F(0) (1 - r), 0), kept
   within ``reach`` of the source's support (elsewhere it is noise), scaled to S's power.
3. Semi-discrete optimal transport of S onto G's lit pixels (framework/optimization/semi_discrete_transport.py):
   every masked height sample, landing at L_j through flat glass, is sent to the point T_j that
   the transport map gives at L_j (linear between the Laguerre cells' centroids).
4. The direction inside the glass that lands on T_j, through whatever lies below the substrate
   (Newton on the operator's own ``land_from_bottom``), and the top normal that
   refracts the arriving light into it (Snell).
5. Heights whose slopes fit those normals (least squares with a small curvature penalty), zero
   outside the mask, summing to the known volume; then projected onto the bounds and the volume
   band. Steps 4-5 are repeated from the new heights ``outer_iterations`` times.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import scipy.sparse as sp
import torch
from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator
from scipy.ndimage import distance_transform_edt, gaussian_filter
from scipy.sparse.linalg import factorized

from framework.core.contracts.start import Start, StartRequest, StartResult
from framework.optimization.semi_discrete_transport import semi_discrete_transport
from operators.image_operator import ImageOperator
from operators.light_paths import flat_exit, refract_down
from operators.optics.inverse_refraction import snell_normals
from operators.values import checked_number, checked_whole
from regularizers import RegularizerContext
from regularizers.volume_prox import VolumeSlabL1Bounds

__all__ = ["TransportStart", "masked_sources", "exit_directions", "fit_masked_surface"]

FD_STEP = 1e-6  # finite-difference step of the Newton solve's Jacobian (direction components)
NOISE_SIGMAS = 3.0  # goal pixels within this many noise standard deviations of zero are black
LANDING_TOLERANCE_PX = 0.5  # a ray landing farther than this from its goal counts as unreached


def light_path_of(operator: ImageOperator) -> ImageOperator:
    """The operator, when it declares ``has_light_path`` (an imaging wrapper passes its inner
    operator's through)."""
    if operator.has_light_path:
        return operator
    raise ValueError(f"operator {type(operator).__name__} exposes no light path (arrivals, land_from_bottom); "
                     "use initial=zero or initial=file")


def receiver_histogram(points: np.ndarray, weights: np.ndarray, n: int, half: float) -> np.ndarray:
    """Sum of ``weights`` per receiver pixel (n, n), rows along y, of ``points`` (N, 2)."""
    ok = np.isfinite(points).all(axis=1)
    image, _, _ = np.histogram2d(points[ok, 1], points[ok, 0], bins=n, range=[[-half, half], [-half, half]],
                                 weights=weights[ok])
    return image


def in_mask(mask: np.ndarray, points: np.ndarray, half_width: float) -> np.ndarray:
    """Whether ``points`` (N, 2) lie on a masked height sample (nearest sample of the m x m grid
    at linspace(-W, W, m))."""
    m = mask.shape[0]
    index = np.rint((points + half_width) / (2.0 * half_width) * (m - 1)).astype(np.int64)
    inside = ((index >= 0) & (index < m)).all(axis=1)
    out = np.zeros(len(points), dtype=bool)
    out[inside] = mask[index[inside, 1], index[inside, 0]]
    return out


def masked_sources(flat: np.ndarray, landings: np.ndarray, flux: np.ndarray, masked: np.ndarray, half: float,
                   blur_px: float) -> np.ndarray:
    """S = F(0) r (n, n): the flat-glass caustic ``flat`` times the share r of each pixel's
    photon flux that entered the top through the mask (``masked``, per photon), both histograms
    blurred by ``blur_px`` pixels."""
    n = flat.shape[-1]
    every = gaussian_filter(receiver_histogram(landings, flux, n, half), blur_px)
    through = gaussian_filter(receiver_histogram(landings, flux * masked, n, half), blur_px)
    share = np.divide(through, every, out=np.zeros_like(every), where=every > 1e-12 * max(every.max(), 1e-300))
    return flat * np.clip(share, 0.0, 1.0)


def exit_directions(path: ImageOperator, points: np.ndarray, tops: np.ndarray, targets: np.ndarray, start: np.ndarray,
                    index: float, steps: int, tolerance: float = 1e-10) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions w (N, 3) inside the glass from the top points ``points`` (N, 2) at heights
    ``tops`` (N,) above the bottom whose rays, refracted out of the flat bottom and traced by the
    operator below it, land on ``targets`` (N, 2); Newton from ``start`` (N, 3) on w's x, y with a
    finite-difference Jacobian, steps limited to 0.2, each ray until it lands within
    ``tolerance`` (scene units) or a step no longer helps. Returns w and the landing error (N,)
    (NaN where a target is NaN or the ray is lost)."""

    def landing(xy: np.ndarray, rows: np.ndarray) -> np.ndarray:
        z = -np.sqrt(np.clip(1.0 - (xy ** 2).sum(axis=1), 1e-12, None))
        w = np.concatenate([xy, z[:, None]], axis=1)
        exits = points[rows] + xy * (tops[rows] / -z)[:, None]
        return path.land_from_bottom(exits, refract_down(w, index))

    xy = start[:, :2].copy()
    every = np.arange(len(xy))
    here = landing(xy, every)
    for _ in range(steps):
        residual = here - targets
        distance = np.linalg.norm(residual, axis=1)
        rows = np.flatnonzero(np.isfinite(distance) & (distance > tolerance))
        if rows.size == 0:
            break
        columns = []
        for k in range(2):
            moved = xy[rows].copy()
            moved[:, k] += FD_STEP
            columns.append((landing(moved, rows) - here[rows]) / FD_STEP)
        jacobian = np.stack(columns, axis=2)  # (R, 2, 2): d landing / d (w_x, w_y)
        r = residual[rows]
        det = jacobian[:, 0, 0] * jacobian[:, 1, 1] - jacobian[:, 0, 1] * jacobian[:, 1, 0]
        good = np.isfinite(det) & (np.abs(det) > 1e-12)
        safe = np.where(good, det, 1.0)
        step = -np.stack([jacobian[:, 1, 1] * r[:, 0] - jacobian[:, 0, 1] * r[:, 1],
                          -jacobian[:, 1, 0] * r[:, 0] + jacobian[:, 0, 0] * r[:, 1]], axis=1) / safe[:, None]
        step *= np.minimum(1.0, 0.2 / np.maximum(np.linalg.norm(step, axis=1), 1e-300))[:, None]
        improved = False
        for scale in (1.0, 0.25, 0.0625):  # damped: a shorter step where the full one lands farther
            trial = xy[rows] + scale * step
            landed = landing(trial, rows)
            better = good & np.isfinite(landed).all(axis=1) & (np.linalg.norm(landed - targets[rows], axis=1)
                                                                < distance[rows])
            xy[rows[better]] = trial[better]
            here[rows[better]] = landed[better]
            improved |= bool(better.any())
            rows, step, good = rows[~better], step[~better], good[~better]
            if rows.size == 0:
                break
        if not improved:
            break
    z = -np.sqrt(np.clip(1.0 - (xy ** 2).sum(axis=1), 1e-12, None))
    return np.concatenate([xy, z[:, None]], axis=1), np.linalg.norm(here - targets, axis=1)


def fit_masked_surface(slopes: np.ndarray, mask: np.ndarray, spacing: float, smoothness: float,
                       height_sum: float | None) -> np.ndarray:
    """Heights (m, m), zero outside ``mask``, whose forward differences best fit ``slopes``
    (m, m, 2: d/dx along columns, d/dy along rows; each edge takes the mean of its ends', exact
    for a quadratic) on every edge that touches the mask, plus
    ``smoothness`` times the squared 5-point Laplacian (per cell); with ``height_sum`` the masked
    heights sum to it exactly (a Lagrange multiplier)."""
    m = mask.shape[0]
    free = np.flatnonzero(mask.ravel())
    eye = sp.identity(m, format="csr")
    diff = sp.diags([-np.ones(m - 1), np.ones(m - 1)], [0, 1], shape=(m - 1, m)) / spacing
    rows, goals = [], []
    edge_slopes = (0.5 * (slopes[:, 1:, 0] + slopes[:, :-1, 0]), 0.5 * (slopes[1:, :, 1] + slopes[:-1, :, 1]))
    for operator, slope in zip((sp.kron(eye, diff, format="csr"), sp.kron(diff, eye, format="csr")), edge_slopes):
        touches = np.abs(operator).dot(mask.ravel().astype(float)) > 0
        rows.append(operator[touches][:, free])
        goals.append(slope.ravel()[touches])
    second = (diff.T @ diff) * spacing
    laplacian = (sp.kron(eye, second) + sp.kron(second, eye)).tocsr()[free][:, free]
    system = sum(r.T @ r for r in rows) + smoothness * (laplacian.T @ laplacian)
    solve = factorized(sp.csc_matrix(system))
    heights = solve(sum(r.T @ g for r, g in zip(rows, goals)))
    if height_sum is not None:
        ones = solve(np.ones(len(free)))
        heights = heights + (height_sum - heights.sum()) / ones.sum() * ones
    out = np.zeros(m * m)
    out[free] = heights
    return out.reshape(m, m)


class TransportStart(Start):
    """The masked transport start (module docstring). Plugin ``initial/transport``.

    Args:
        photons: Photons traced through flat glass for the masked share and the arriving
            directions (the operator's light, its seed).
        reach: Receiver pixels farther than this fraction of the receiver's width from the masked
            region's flat-glass light are not given any of it.
        black_level: Goal pixels below this fraction of the brightest get no transport site.
        smoothness: Weight of the squared Laplacian against the slope misfit (dimensionless).
        p1: Lower bound of the heights on the mask, scene units.
        p2: Upper bound of the heights on the mask, scene units.
        volume_tolerance: With a known volume, the start's masked heights sum to it within this
            relative band.
        outer_iterations: Rounds of steps 4-5 (the arriving light is taken at the new heights).
        newton_steps: Newton steps for the directions inside the glass.
        mass_tolerance: The transport's accuracy (framework/optimization/semi_discrete_transport.py).
    """

    length_keys = ("p1", "p2")  # may be given with a unit, e.g. '0.4 mm' (framework/core/plugin_config.py)

    name = "transport"

    def __init__(self, photons: int = 262144, reach: float = 0.05, black_level: float = 1e-3, smoothness: float = 0.1,
                 p1: float = 0.0, p2: float = 0.3, volume_tolerance: float = 0.02, outer_iterations: int = 2,
                 newton_steps: int = 20, mass_tolerance: float = 1e-3) -> None:
        photons, outer_iterations, newton_steps = (checked_whole(value, f"initial.{key}", 1) for key, value in (
            ("photons", photons), ("outer_iterations", outer_iterations), ("newton_steps", newton_steps)))
        for key, value, low, high in (("reach", reach, 0.0, 1.0), ("black_level", black_level, 0.0, 1.0),
                                      ("volume_tolerance", volume_tolerance, 0.0, 1.0),
                                      ("mass_tolerance", mass_tolerance, 0.0, 1.0)):
            checked_number(value, f"initial.{key}", above=low, below=high, must=f"must lie in ({low}, {high})")
        checked_number(smoothness, "initial.smoothness", 0.0)
        if not (isinstance(p1, (int, float)) and isinstance(p2, (int, float)) and 0.0 <= p1 < p2 < math.inf):
            raise ValueError(f"initial.p1={p1!r}, initial.p2={p2!r} must satisfy 0 <= p1 < p2 (scene units)")
        self.photons, self.reach, self.black_level, self.smoothness = (
            photons,
            float(reach),
            float(black_level),
            float(smoothness),
        )
        self.p1, self.p2, self.volume_tolerance = float(p1), float(p2), float(volume_tolerance)
        self.outer_iterations, self.newton_steps, self.mass_tolerance = (
            outer_iterations,
            newton_steps,
            float(mass_tolerance),
        )

    def __call__(self, request: StartRequest) -> StartResult:
        started = time.perf_counter()
        problem = request.problem
        path = light_path_of(problem.operator)
        mask = problem.data.mask.cpu().numpy().astype(bool)
        if not mask.any():
            raise ValueError("data.mask has no printed cell: the transport start moves the light of the masked region; "
                             "give a mask with the printed area (or use initial=zero)")
        bounds = self._bounds(problem, mask)
        arrivals = path.arrivals(self.photons)
        plan = self._plan(problem, path, arrivals, mask, request.deadline)
        d, error = self._heights(problem, path, arrivals, mask, plan, bounds)
        pixel = problem.scene.receiver.pixel_size
        metrics = {"transport_sites": float(len(plan.sites)), "transport_newton_steps": float(plan.newton_steps),
                   "transport_max_relative_mass_error": plan.max_relative_mass_error,
                   "transport_converged": float(plan.converged),
                   "transport_landing_error_px": float(np.median(error[np.isfinite(error)]) / pixel),
                   "transport_unreached_samples": float(np.sum(~(error <= LANDING_TOLERANCE_PX * pixel))),
                   "transport_seconds": time.perf_counter() - started}
        if problem.data.volume is not None:
            metrics["transport_volume_ratio"] = float(d.sum() * problem.grid.cell_area / problem.data.volume)
        return StartResult(torch.from_numpy(d).to(problem.operator.dtype), metrics, self.name, shaped=True)

    def _plan(self, problem: Any, path: ImageOperator, arrivals: Any, mask: np.ndarray, deadline: float | None) -> Any:
        """Steps 1-3: the masked region's flat-glass light, the goal, and the transport between them
        (its Newton stopped at ``deadline``, a ``time.perf_counter()`` value, if it comes first)."""
        operator, grid, scene, data = problem.operator, problem.grid, problem.scene, problem.data
        half, index = scene.receiver.half_width, float(np.mean(scene.indices))
        flat = operator.render(torch.zeros(grid.shape, dtype=operator.dtype)).double().sum(dim=0).cpu().numpy()
        target = data.target.detach().double().sum(dim=0).cpu().numpy()
        landings = path.land_from_bottom(*flat_exit(arrivals.points, arrivals.directions, index, grid.base))
        source = masked_sources(flat, landings, arrivals.flux, in_mask(mask, arrivals.points, grid.half_width), half,
                                blur_px=1.0)
        if source.sum() <= 1e-9 * max(flat.sum(), 1e-300):
            raise ValueError("the masked region's light reaches no receiver pixel through flat glass; check data.mask "
                             "and the receiver (receiver.z, receiver.half_width)")
        pixel = scene.receiver.pixel_size
        support = source > 1e-3 * source.max()
        near = distance_transform_edt(~support) * pixel <= self.reach * 2.0 * half
        goal = np.where(near, np.clip(target - (flat - source), 0.0, None), 0.0)
        if not goal.max() > 0.0:
            raise ValueError("the caustic has no light within reach of the masked region (initial.reach="
                             f"{self.reach}); check that data.mask and the image are aligned, or raise initial.reach")
        # Black: below black_level of the brightest, or within three standard deviations of the
        # noise (delta ||b|| spread evenly over the pixels).
        noise = NOISE_SIGMAS * data.delta * float(np.linalg.norm(target)) / math.sqrt(target.size)
        lit = goal > max(self.black_level * goal.max(), noise)
        if not lit.any():
            raise ValueError(f"the caustic within reach of the masked region is below its noise level (data.delta="
                             f"{data.delta}); check data.mask, data.delta and the image")
        centres = (np.arange(flat.shape[-1]) + 0.5) * pixel - half
        rx, ry = np.meshgrid(centres, centres)
        # A faint floor (1e-3 of the masked light's mean) keeps every Laguerre cell's mass above
        # zero, which the transport's Newton iteration needs from its Voronoi start.
        floor = 1e-3 * float(source[support].mean())
        return semi_discrete_transport(source + floor, -half, half, np.stack([rx[lit], ry[lit]], axis=1), goal[lit],
                                       self.mass_tolerance, deadline)

    def _heights(self, problem: Any, path: ImageOperator, arrivals: Any, mask: np.ndarray, plan: Any,
                 bounds: Any) -> tuple[np.ndarray, np.ndarray]:
        """Steps 4-5: the heights (m, m) that send each masked sample's light to its goal point,
        and each sample's landing error (scene units; NaN where its light is lost)."""
        grid, scene, data = problem.grid, problem.scene, problem.data
        index, h = float(np.mean(scene.indices)), grid.base
        coords = np.linspace(-grid.half_width, grid.half_width, grid.resolution)
        gx, gy = np.meshgrid(coords, coords)
        points = np.stack([gx[mask], gy[mask]], axis=1)
        incident_at = _direction_field(arrivals, scene.light.position, problem.operator, points)
        incident = incident_at(np.full(len(points), h))
        goals = _mapped(plan, path.land_from_bottom(*flat_exit(points, incident, index, h)))
        d = np.zeros(grid.shape)
        inside = refract_down(incident, 1.0 / index)
        error = np.zeros(len(points))
        height_sum = None if data.volume is None else data.volume / grid.cell_area
        for _ in range(self.outer_iterations):
            tops = h + d[mask]
            incident = incident_at(tops)
            inside, error = exit_directions(path, points, tops, goals, inside, index, self.newton_steps)
            normals = snell_normals(incident, inside, index)
            slopes = np.zeros((*grid.shape, 2))
            slopes[mask] = -normals[:, :2] / normals[:, 2:3]
            d = fit_masked_surface(slopes, mask, coords[1] - coords[0], self.smoothness, height_sum)
            d = bounds(torch.from_numpy(d)).numpy()
        return d, error

    def _bounds(self, problem: Any, mask: np.ndarray):
        """The projection onto {p1 <= d <= p2 on the mask, 0 off it, and the volume band}."""
        context = problem.context
        if context.volume is None:
            return lambda d: torch.where(torch.from_numpy(mask), d.clamp(self.p1, self.p2), torch.zeros_like(d))
        band = VolumeSlabL1Bounds(alpha=0.0, p1=self.p1, p2=self.p2, v_eps=self.volume_tolerance)
        band.setup(
            RegularizerContext(mask=torch.from_numpy(mask), volume=context.volume, pixel_area=context.pixel_area)
        )
        return lambda d: band.prox(d, 1.0)


def _direction_field(arrivals: Any, light: tuple[float, float, float], operator: Any, points: np.ndarray):
    """A function of the heights (N,) at the top points ``points`` (N, 2) giving the unit
    directions (N, 3) of the light arriving there: straight from the light for the height-field
    operator's open scene, else interpolated once at the points' x, y between the traced arrivals
    (at most 65536 of them; nearest outside their hull)."""
    if not operator.elements:
        source = np.asarray(light, dtype=np.float64)

        def straight(tops: np.ndarray) -> np.ndarray:
            ray = np.concatenate([points, tops[:, None]], axis=1) - source
            return ray / np.linalg.norm(ray, axis=1, keepdims=True)
        return straight
    pick = np.linspace(0, len(arrivals.points) - 1, min(len(arrivals.points), 65536)).astype(np.int64)
    traced = LinearNDInterpolator(arrivals.points[pick], arrivals.directions[pick])(points)
    missing = ~np.isfinite(traced).all(axis=1)
    traced[missing] = NearestNDInterpolator(arrivals.points[pick], arrivals.directions[pick])(points[missing])
    traced /= np.linalg.norm(traced, axis=1, keepdims=True)
    return lambda tops: traced


def _mapped(plan: Any, landing: np.ndarray) -> np.ndarray:
    """The transport map at ``landing`` (N, 2): each Laguerre cell's centroid goes to its site,
    linear between centroids; outside their hull the nearest centroid's displacement; NaN where
    the landing is (the light of that sample is lost through flat glass)."""
    shift = plan.sites - plan.centroids
    known = np.isfinite(landing).all(axis=1)  # samples whose flat-glass light is lost get no goal (NaN)
    moved = np.full_like(landing, np.nan)
    moved[known] = LinearNDInterpolator(plan.centroids, shift)(landing[known])
    missing = known & ~np.isfinite(moved).all(axis=1)
    if missing.any():
        moved[missing] = NearestNDInterpolator(plan.centroids, shift)(landing[missing])
    return landing + moved
