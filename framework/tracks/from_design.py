"""A print's tracks from its design height field: the skeleton of its beads as paths, then the
profiles that draw the design best.

1. The printed area (heights above ``floor`` of the local peak) is thinned to its skeleton
   (scikit-image's skeletonize); the skeleton's branches between its ends and junctions become
   polylines, spurs shorter than ``spur_mm`` are dropped, and at each junction the two branches
   that continue each other most straightly are joined (two beads that cross stay two tracks).
2. Each track starts with the design's height along its path and the width of a Gaussian bead of
   the cross-section's area; then every profile (height, width, offset, shape) is fitted to the
   design's heights by least squares (L-BFGS-B over the representation's exact gradient,
   framework/tracks/track_heights.py), so the nominal tracks redraw the design. A tool path given
   with a design keeps its paths and takes its profiles and bead shapes from the design the same way
   (:func:`profiles_drawing`): the design knows how the glass lies, the tool path where.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import torch
from scipy import ndimage, optimize
from skimage.morphology import skeletonize

from framework.tracks.geometry import frame_at, resampled_path
from framework.tracks.track_heights import TrackHeights, TrackSettings
from framework.tracks.track_set import SECTION_REACH, SECTION_SAMPLES, Track, TrackSet

__all__ = ["tracks_from_design", "skeleton_tracks", "skeleton_paths", "profiles_drawing", "measured_sections"]

NEIGHBOURS = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc]


def _branches(skeleton: np.ndarray) -> list[list[tuple[int, int]]]:
    """The skeleton's branches: pixel chains between nodes (ends, junctions), each node shared."""
    on = {(int(r), int(c)) for r, c in zip(*np.nonzero(skeleton))}

    def neighbours(p: tuple[int, int]) -> list[tuple[int, int]]:
        return [(p[0] + dr, p[1] + dc) for dr, dc in NEIGHBOURS if (p[0] + dr, p[1] + dc) in on]

    nodes = {p for p in on if len(neighbours(p)) != 2}
    seen: set[frozenset[tuple[int, int]]] = set()
    branches: list[list[tuple[int, int]]] = []
    for node in nodes:
        for first in neighbours(node):
            chain, previous, here = [node, first], node, first
            while here not in nodes:
                onward = [q for q in neighbours(here) if q != previous and q not in chain[-3:]]
                if not onward:
                    break
                previous, here = here, onward[0]
                chain.append(here)
            key = frozenset(chain)
            if key not in seen:
                seen.add(key)
                branches.append(chain)
    loops = on - {p for chain in branches for p in chain}
    while loops:  # closed rings have no node: start anywhere
        start = loops.pop()
        chain, previous, here = [start], (-1, -1), start
        while True:
            onward = [q for q in neighbours(here) if q != previous and q in loops]
            if not onward:
                break
            previous, here = here, onward[0]
            loops.discard(here)
            chain.append(here)
        if len(chain) > 2:
            branches.append([*chain, start])
    return branches


def _direction(chain: np.ndarray, at_end: bool, reach: int = 6) -> np.ndarray:
    """The unit direction a chain leaves its first (or last) point with, over ``reach`` pixels."""
    part = chain[::-1] if at_end else chain
    step = part[min(reach, len(part) - 1)] - part[0]
    return step / max(float(np.hypot(*step)), 1e-12)


def _joined(chains: list[np.ndarray]) -> list[np.ndarray]:
    """Chains joined through junctions: at each shared end, the pair that continues most straightly
    (an angle under 45 degrees) becomes one chain; repeated until no pair joins (the straightest
    pair first; of equals, the first by chain index, then by end). Ends are met by a table of end
    points, so a noisy fit's skeleton of thousands of chains joins in seconds."""
    chains = [c for c in chains if len(c) >= 2]
    while True:
        ends: dict[tuple[float, ...], list[tuple[int, bool]]] = {}
        for i, chain in enumerate(chains):
            for end in (False, True):
                ends.setdefault(tuple(chain[-1] if end else chain[0]), []).append((i, end))
        candidates = []
        for members in ends.values():
            for i, end_a in members:
                if np.array_equal(chains[i][0], chains[i][-1]):  # a loop starts no join
                    continue
                for j, end_b in members:
                    if j > i:
                        straight = -float(np.dot(_direction(chains[i], end_a), _direction(chains[j], end_b)))
                        if straight > math.cos(math.pi / 4):
                            candidates.append((straight, i, j, end_a, end_b))
        if not candidates:
            return chains
        _, i, j, end_a, end_b = min(candidates, key=lambda c: (-c[0], c[1], c[2], c[3], c[4]))
        a = chains[i] if end_a else chains[i][::-1]
        b = chains[j][::-1] if end_b else chains[j]
        chains = [c for k, c in enumerate(chains) if k not in (i, j)] + [np.concatenate([a, b[1:]])]


def _collapsed(chains: list[np.ndarray], nodes: dict[tuple, int], cell_mm: float, link_mm: float
               ) -> list[np.ndarray]:
    """Short links between two junctions removed and their junctions made one point (their mean):
    beads crossing at a slant thin to two junctions joined by a link, not to one."""
    parent: dict[tuple, tuple] = {}

    def root(p: tuple) -> tuple:
        while parent.get(p, p) != p:
            p = parent[p]
        return p

    links = [c for c in chains if len(c) * cell_mm < link_mm and min(nodes[tuple(c[0])], nodes[tuple(c[-1])]) > 1
             and tuple(c[0]) != tuple(c[-1])]
    for link in links:
        parent[root(tuple(link[0]))] = root(tuple(link[-1]))
    members: dict[tuple, list[tuple]] = {}
    for point in parent:
        members.setdefault(root(point), []).append(point)
    centre = {p: np.mean([*group, r], axis=0) for r, group in members.items() for p in [*group, r]}
    out = []
    for chain in chains:
        if any(chain is link for link in links):
            continue
        chain = chain.copy()
        for end in (0, -1):
            if tuple(chain[end]) in centre:
                chain[end] = centre[tuple(chain[end])]
        out.append(chain)
    return out


def _valleys(design: np.ndarray) -> np.ndarray:
    """Where the design (m, m) curves up more than it curves down (smoothed over 1.4 samples): the
    troughs between beads, the outer flanks of their tails, a dip along a bead. Left out of the
    printed area where it is below half the local peak, they keep two beads whose tails overlap
    apart; exactly flat parts (a flat-topped bead) stay in."""
    design = np.asarray(design, dtype=np.float64)
    d_rr, d_cc, d_rc = (ndimage.gaussian_filter(design, math.sqrt(2.0), order=order)
                        for order in ((2, 0), (0, 2), (1, 1)))
    mean, spread = 0.5 * (d_rr + d_cc), np.sqrt(0.25 * (d_rr - d_cc) ** 2 + d_rc**2)
    upward, downward = mean + spread, mean - spread  # the Hessian's eigenvalues
    return upward > np.maximum(np.abs(downward), 1e-4 * float(np.max(design)))


def _degrees(chains: list[np.ndarray]) -> dict[tuple, int]:
    """How many chains end at each chain end (pixel): 1 at a free end, 3 or more at a junction."""
    degrees: dict[tuple, int] = {}
    for chain in chains:
        for end in (tuple(chain[0]), tuple(chain[-1])):
            degrees[end] = degrees.get(end, 0) + 1
    return degrees


def skeleton_paths(design_mm: np.ndarray, cell_mm: float, floor: float = 0.2, spur_mm: float = 1.0,
                   smooth_mm: float = 0.5) -> list[np.ndarray]:
    """The bead paths (k, 2) in mm (x, y from the grid's centre) of a design (m, m) in mm."""
    peak = float(design_mm.max())
    if not peak > 0.0:
        raise ValueError("the design has no printed height; tracks need beads to follow")
    local = ndimage.maximum_filter(design_mm, size=2 * max(1, int(round(2.0 / cell_mm))) + 1)
    printed = (design_mm > floor * local) & (design_mm > 0.05 * peak)
    printed &= ~(_valleys(design_mm) & (design_mm < 0.5 * local))
    chains = [np.asarray(c, dtype=np.float64) for c in _branches(skeletonize(printed))]
    half_width = ndimage.distance_transform_edt(printed) * cell_mm  # mm to the printed area's edge
    nodes = _degrees(chains)

    def spur(chain: np.ndarray) -> bool:  # a short branch with a free end: a fork where a wide bead ends
        ends = [tuple(chain[0]), tuple(chain[-1])]
        if min(nodes[e] for e in ends) > 1:
            return False
        junction = max(ends, key=lambda e: nodes[e])
        return len(chain) * cell_mm < max(spur_mm, 2.0 * float(half_width[int(junction[0]), int(junction[1])]))

    kept = [c for c in chains if not spur(c)]
    nodes = _degrees(kept)
    kept = _collapsed(kept, nodes, cell_mm, link_mm=1.5)
    m = design_mm.shape[0]
    paths = []
    for chain in _joined(kept):
        if len(chain) * cell_mm < spur_mm:
            continue
        width = max(1, int(round(smooth_mm / cell_mm)))
        smoothed = ndimage.uniform_filter1d(chain, size=2 * width + 1, axis=0, mode="nearest")
        smoothed[0], smoothed[-1] = chain[0], chain[-1]
        free = [nodes.get(tuple(chain[end])) == 1 and not np.array_equal(chain[0], chain[-1]) for end in (0, -1)]
        centre = (m - 1) / 2.0
        path = np.stack([(smoothed[:, 1] - centre) * cell_mm, (smoothed[:, 0] - centre) * cell_mm], axis=1)
        paths.append(_ends_extended(path, free, design_mm, cell_mm))
    if not paths:
        raise ValueError("the design's skeleton has no branch longer than spur_mm; is it a print of beads?")
    return paths


def _design_at(design_mm: np.ndarray, xy: np.ndarray, cell_mm: float) -> np.ndarray:
    """The design (m, m, mm) at points xy (p, 2) in mm from the grid's centre (bilinear; 0 outside)."""
    centre = (design_mm.shape[0] - 1) / 2.0
    return ndimage.map_coordinates(design_mm, [xy[:, 1] / cell_mm + centre, xy[:, 0] / cell_mm + centre], order=1)


def _ends_extended(path: np.ndarray, free: list[bool], design_mm: np.ndarray, cell_mm: float,
                   inner_mm: float = 1.0, aim_mm: float = 3.0, level: float = 0.97, reach_mm: float = 5.0
                   ) -> np.ndarray:
    """The path (k, 2) in mm with each free end (``free``: first, last) cut back by ``inner_mm``
    and carried on straight, in the direction of its last ``aim_mm``, while the design's height
    stays at ``level`` of the height where it was cut. Thinning stops short of a bead's end by about
    half its width and bends there (a wide bead's end thins to a fork whose spurs are dropped); the
    drawn bead's round end then starts where the design's starts to fall
    (framework/tracks/geometry.py, ``beyond``)."""
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
    aim = min(aim_mm, 0.5 * along[-1])
    if aim <= inner_mm + cell_mm:
        return path
    steps = np.arange(0.0, reach_mm + inner_mm, 0.5 * cell_mm)

    def tip(arc_inner: float, arc_aim: float) -> np.ndarray:
        inner = np.array([np.interp(arc_inner, along, path[:, 0]), np.interp(arc_inner, along, path[:, 1])])
        behind = np.array([np.interp(arc_aim, along, path[:, 0]), np.interp(arc_aim, along, path[:, 1])])
        direction = (inner - behind) / max(float(np.hypot(*(inner - behind))), 1e-12)
        ahead = _design_at(design_mm, inner[None] + steps[:, None] * direction[None], cell_mm)
        falls = np.nonzero(ahead < level * ahead[0])[0]
        return inner + steps[max(int(falls[0]) - 1, 0) if falls.size else -1] * direction

    keep = (along > (inner_mm if free[0] else -1.0)) & (along < (along[-1] - inner_mm if free[1] else np.inf))
    head = [tip(inner_mm, aim)] if free[0] else []
    tail = [tip(along[-1] - inner_mm, along[-1] - aim)] if free[1] else []
    return np.concatenate([np.asarray(head).reshape(-1, 2), path[keep], np.asarray(tail).reshape(-1, 2)])


def _first_guess(design_mm: np.ndarray, path: np.ndarray, cell_mm: float, name: str) -> Track:
    """Height along the path from the design; width: the median full width at half height across it."""
    m = design_mm.shape[0]
    centre = (m - 1) / 2.0
    rows, cols = path[:, 1] / cell_mm + centre, path[:, 0] / cell_mm + centre
    height = np.maximum(ndimage.map_coordinates(design_mm, [rows, cols], order=1), 1e-3)
    tangent = np.gradient(path, axis=0)
    tangent /= np.maximum(np.hypot(*tangent.T), 1e-12)[:, None]
    across = np.linspace(-3.0, 3.0, int(round(6.0 / (0.5 * cell_mm))) + 1)  # mm
    r = rows[:, None] + across[None] * tangent[:, 0:1] / cell_mm  # the normal (-t_y, t_x) in (row, col)
    c = cols[:, None] - across[None] * tangent[:, 1:2] / cell_mm
    profile = ndimage.map_coordinates(design_mm, [r, c], order=1)
    above = profile >= 0.5 * height[:, None]
    width = float(np.median(np.count_nonzero(above, axis=1))) * (across[1] - across[0])
    width = max(width, 2.0 * cell_mm)
    return Track(name, path, height, np.full(height.size, width), np.zeros(height.size))


def tracks_from_design(design: np.ndarray, half_width: float, mm_per_unit: float, settings: TrackSettings,
                       iterations: int = 300) -> TrackSet:
    """The tracks whose beads draw the design (m, m) (scene units on [-W, W]^2) best (module docstring)."""
    return profiles_drawing(skeleton_tracks(design, half_width, mm_per_unit), design, half_width, mm_per_unit,
                            settings, iterations)


def skeleton_tracks(heights: np.ndarray, half_width: float, mm_per_unit: float) -> TrackSet:
    """A height field (m, m, scene units: a design or a fit) as tracks along its skeleton, each with
    the heights along its path and its median width at half height (no profiles fitted)."""
    m = heights.shape[0]
    cell_mm = 2.0 * half_width * mm_per_unit / (m - 1)
    heights_mm = np.asarray(heights, dtype=np.float64) * mm_per_unit
    paths = skeleton_paths(heights_mm, cell_mm)
    return TrackSet(tuple(_first_guess(heights_mm, p, cell_mm, f"track {i + 1}") for i, p in enumerate(paths)))


def profiles_drawing(tracks: TrackSet, design: np.ndarray, half_width: float, mm_per_unit: float,
                     settings: TrackSettings, iterations: int = 300) -> TrackSet:
    """The tracks (their paths kept) with the cross-sections and profiles that draw the design (m, m,
    scene units) best: the power-cap profiles fitted first, then each bead's own section measured
    from the design (:func:`measured_sections`) and the profiles fitted again with it."""
    family = _least_squares(tracks, design, half_width, mm_per_unit, settings, iterations)
    cell_mm = 2.0 * half_width * mm_per_unit / (design.shape[0] - 1)
    measured = measured_sections(family, np.asarray(design, dtype=np.float64) * mm_per_unit, cell_mm)
    return _least_squares(measured, design, half_width, mm_per_unit, settings, iterations)


def measured_sections(tracks: TrackSet, design_mm: np.ndarray, cell_mm: float) -> TrackSet:
    """Each track with its own cross-section: the design across the path at v = 2 r / width of each
    knot (both sides averaged, over the knot's height), the median over the knots one width and more
    from the path's ends and two widths and more from every other track, made 1 at v = 0,
    non-increasing, and stretched so that it falls to 1/2 at v = 1. A track with no such knot keeps
    its power cap."""
    v = np.linspace(0.0, SECTION_REACH, SECTION_SAMPLES)
    dense = [resampled_path(t.path, 0.25) for t in tracks.tracks]
    out = []
    for index, track in enumerate(tracks.tracks):
        arcs = track.knot_arcs()
        samples = []
        for k, arc in enumerate(arcs):
            width = track.width[k]
            if arc < width or arc > arcs[-1] - width or track.height[k] <= 0.0:
                continue
            point, normal = frame_at(dense[index], arc)
            others = [np.min(np.hypot(*(p - point).T)) for j, p in enumerate(dense) if j != index]
            if others and min(others) < 2.0 * width + float(np.max(track.width)):
                continue
            centre_mm = point + track.offset[k] * normal
            sides = [_design_at(design_mm, centre_mm[None] + sign * (v * width / 2.0)[:, None] * normal[None], cell_mm)
                     for sign in (1.0, -1.0)]
            samples.append(0.5 * (sides[0] + sides[1]) / track.height[k])
        if not samples:
            out.append(track)
            continue
        section = np.median(np.asarray(samples), axis=0)
        section = np.minimum.accumulate(np.clip(section / section[0], 0.0, 1.0))
        half = float(np.interp(0.5, section[::-1], v[::-1]))  # where it falls to 1/2
        stretched = np.interp(v * half, v, section, right=0.0)
        out.append(replace(track, section=stretched, width=track.width * half))
    return replace(tracks, tracks=tuple(out))


def _least_squares(tracks: TrackSet, design: np.ndarray, half_width: float, mm_per_unit: float,
                     settings: TrackSettings, iterations: int = 300) -> TrackSet:
    """The tracks (their paths and sections kept, no gaps opened) with the profiles and shapes that draw
    the design (m, m, scene units) best: least squares over the representation's exact gradient (L-BFGS-B)."""
    m = design.shape[0]
    beads_only = TrackSettings(**{**settings.__dict__, "residual_mm": 0.0, "gaps": 0, "spare_drops": 0})
    representation = TrackHeights(tracks, m, half_width, mm_per_unit, beads_only)
    target = torch.from_numpy(np.asarray(design, dtype=np.float64))
    scale = representation.scale()

    def objective(z: np.ndarray) -> tuple[float, np.ndarray]:
        theta = (torch.from_numpy(z) * scale).requires_grad_(True)
        value = 0.5 * torch.sum((representation.drawn(theta) - target) ** 2)  # one pass, value and gradient
        (grad,) = torch.autograd.grad(value, theta)
        return float(value.detach()), (grad * scale).numpy()

    lower, upper = representation.bounds()
    z0 = (representation.initial() / scale).numpy()
    bounds = list(zip((lower / scale).numpy(), (upper / scale).numpy()))
    found = optimize.minimize(objective, z0, jac=True, method="L-BFGS-B", bounds=bounds,
                              options={"maxiter": iterations})
    return representation.track_set(torch.from_numpy(found.x) * scale)
