"""The geometry of a photo of the receiver: the receiver's four corners in the photo, the
homography they determine, and the receiver image resampled from the photo through it.

Photo pixel coordinates are (col, row) = (x, y) with row 0 at the top and pixel centres at
integer coordinates, so a photo of shape (H, W) covers [-0.5, W - 0.5] x [-0.5, H - 0.5]. Receiver
images follow framework/files/image_io.py: (c, n, n) with [row, col] = [y, x], row 0 at y = -W, pixel
centres at -W + (p + 0.5) 2W / n (docs/photo_import.md).
"""

from __future__ import annotations

import numpy as np

from operators.values import checked_number, checked_whole

__all__ = ["CORNER_NAMES", "CORNER_ORDER", "RECEIVER_CORNERS", "MIN_AREA_PX", "MAX_SUPERSAMPLE", "check_corners",
           "homography", "project_points", "bilinear_samples", "check_receiver_grid", "rectify",
           "saturated_receiver_pixels", "inside_receiver"]

CORNER_NAMES = ("bottom-left (-W, -W)", "bottom-right (W, -W)", "top-right (W, W)", "top-left (-W, W)")
RECEIVER_CORNERS = ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0))  # those corners over W
CORNER_ORDER = "receiver bottom-left, bottom-right, top-right, top-left"
MIN_AREA_PX = 16.0  # a quadrilateral smaller than 4 x 4 photo pixels is degenerate


def _as_corners(corners: object) -> np.ndarray:
    try:
        array = np.array(corners, dtype=np.float64)
    except (TypeError, ValueError):
        array = None
    if array is None or array.shape != (4, 2):
        shape = None if array is None else array.shape
        raise ValueError(f"data.corners {corners!r} (shape {shape}) must be four [x, y] photo pixel coordinates "
                         f"(x = column, y = row from the top) in the order {CORNER_ORDER}")
    if not np.isfinite(array).all():
        raise ValueError(f"data.corners {array.tolist()} contain NaN or infinite values")
    return array


def check_corners(corners: object, photo_shape: tuple[int, ...]) -> np.ndarray:
    """The corners as float64 (4, 2) [[col, row], ...] after checking them against a photo of
    shape (H, W[, 3]): inside it, a convex, non-degenerate quadrilateral in the order receiver
    bottom-left, bottom-right, top-right, top-left (either orientation: a mirrored view is allowed).
    """
    array = _as_corners(corners)
    height, width = photo_shape[0], photo_shape[1]
    outside = ((array[:, 0] < -0.5) | (array[:, 0] > width - 0.5)
               | (array[:, 1] < -0.5) | (array[:, 1] > height - 0.5))
    if outside.any():
        k = int(np.argmax(outside))
        raise ValueError(f"data.corners: corner {CORNER_NAMES[k]} [x, y] = {array[k].tolist()} lies outside the "
                         f"{width} x {height} photo (x in [-0.5, {width - 0.5}], y in [-0.5, {height - 0.5}]); "
                         "corners are photo pixel coordinates, column then row")
    edges = np.roll(array, -1, axis=0) - array  # edge k runs from corner k to corner k + 1
    before = np.roll(edges, 1, axis=0)
    cross = before[:, 0] * edges[:, 1] - before[:, 1] * edges[:, 0]  # turn at each corner
    area = 0.5 * abs(float(np.sum(array[:, 0] * np.roll(array[:, 1], -1) - np.roll(array[:, 0], -1) * array[:, 1])))
    positive = int(np.sum(cross > 0))
    if positive == 2:
        raise ValueError(f"data.corners {array.tolist()} form a self-intersecting quadrilateral: the order must go "
                         f"around the receiver, {CORNER_ORDER}")
    lengths = np.linalg.norm(edges, axis=1)
    flat = np.abs(cross) <= 1e-3 * lengths * np.roll(lengths, 1)
    if area < MIN_AREA_PX or flat.any():
        raise ValueError(f"data.corners {array.tolist()} span a degenerate quadrilateral "
                         f"(area {area:.3g} photo pixels^2"
                         + (f", collinear at {CORNER_NAMES[int(np.argmax(flat))]}" if flat.any() else "")
                         + "); give the receiver's four distinct corners")
    if positive in (1, 3):
        odd = int(np.argmax((cross > 0) != (positive == 3)))
        raise ValueError(f"data.corners {array.tolist()} form a quadrilateral that is not convex (at corner "
                         f"{CORNER_NAMES[odd]} {array[odd].tolist()}); a flat receiver is always seen convex: "
                         "check the coordinates")
    return array


def homography(corners: object, half_width: float) -> np.ndarray:
    """H (3, 3) mapping receiver (x, y) in scene units to photo (col, row) pixels, exact at the
    four corners (DLT with normalised coordinates; H[2, 2] = 1).

    >>> H = homography([[10, 90], [90, 90], [90, 10], [10, 10]], half_width=1.0)
    >>> p = H @ [1.0, 1.0, 1.0]; (p[:2] / p[2]).round(9).tolist()
    [90.0, 10.0]
    """
    dst = _as_corners(corners)
    _check_half_width(half_width)
    src = np.asarray(RECEIVER_CORNERS)
    centre = dst.mean(axis=0)
    scale = np.sqrt(2.0) / max(float(np.linalg.norm(dst - centre, axis=1).mean()), 1e-300)
    norm = (dst - centre) * scale
    x, y, u, v = src[:, 0], src[:, 1], norm[:, 0], norm[:, 1]
    one, zero = np.ones(4), np.zeros(4)
    rows = np.stack([np.stack([x, y, one, zero, zero, zero, -u * x, -u * y, -u], axis=1),
                     np.stack([zero, zero, zero, x, y, one, -v * x, -v * y, -v], axis=1)], axis=1).reshape(8, 9)
    _, singular, vt = np.linalg.svd(rows)
    if singular[-1] <= 1e-9 * singular[0]:
        raise ValueError(f"data.corners {dst.tolist()} do not determine a homography (three are collinear)")
    h_norm = vt[-1].reshape(3, 3)
    to_pixels = np.array([[1.0 / scale, 0.0, centre[0]], [0.0, 1.0 / scale, centre[1]], [0.0, 0.0, 1.0]])
    from_receiver = np.diag([1.0 / half_width, 1.0 / half_width, 1.0])
    h = to_pixels @ h_norm @ from_receiver
    return h / h[2, 2]


def project_points(h: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points (x, y) mapped through the homography h (arrays of one shape)."""
    w = h[2, 0] * x + h[2, 1] * y + h[2, 2]
    return (h[0, 0] * x + h[0, 1] * y + h[0, 2]) / w, (h[1, 0] * x + h[1, 1] * y + h[1, 2]) / w


def _support(col: np.ndarray, row: np.ndarray, shape: tuple[int, int]):
    """Top-left pixel (r0, c0) of the 2 x 2 bilinear support of points (col, row), clamped to the
    photo (border padding), and the fractional offsets (tr, tc) inside it."""
    height, width = shape
    col = np.clip(col, 0.0, width - 1.0)
    row = np.clip(row, 0.0, height - 1.0)
    c0 = np.minimum(np.floor(col).astype(np.intp), max(width - 2, 0))
    r0 = np.minimum(np.floor(row).astype(np.intp), max(height - 2, 0))
    return r0, c0, row - r0, col - c0


def bilinear_samples(image: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """Bilinear samples (..., C) of ``image`` (H, W, C) at (col, row), pixel centres at integers."""
    height, width = image.shape[:2]
    r0, c0, tr, tc = _support(col, row, (height, width))
    r1, c1 = np.minimum(r0 + 1, height - 1), np.minimum(c0 + 1, width - 1)
    tr, tc = tr[..., None], tc[..., None]
    top = (1.0 - tc) * image[r0, c0] + tc * image[r0, c1]
    bottom = (1.0 - tc) * image[r1, c0] + tc * image[r1, c1]
    return (1.0 - tr) * top + tr * bottom


MAX_SUPERSAMPLE = 16


def check_receiver_grid(resolution: int, half_width: float, supersample: int) -> tuple[int, int]:
    """(resolution, supersample) as ints, once they and ``half_width`` are checked."""
    resolution = checked_whole(resolution, "receiver.resolution", 1, must="must be a positive integer")
    supersample = checked_whole(supersample, "data.supersample", 1, must="must be a positive integer")
    if supersample > MAX_SUPERSAMPLE:
        raise ValueError(f"data.supersample={supersample} must be at most {MAX_SUPERSAMPLE} (samples per receiver "
                         "pixel and axis; 4 is plenty)")
    _check_half_width(half_width)
    return resolution, supersample


def _check_half_width(half_width: float) -> None:
    checked_number(half_width, "receiver.half_width", above=0.0, unit="scene units")


def _receiver_blocks(h: np.ndarray, resolution: int, half_width: float, supersample: int):
    """Photo (col, row) of the supersample^2 sub-samples of receiver pixels, in blocks of receiver
    rows: yields (first row, last row + 1, col, row) with col/row of shape (rows * s, n * s)."""
    s, n = supersample, resolution
    coords = half_width * (2.0 * (np.arange(n * s) + 0.5) / (n * s) - 1.0)
    rows_per_block = max(1, (1 << 21) // (n * s * s))
    for first in range(0, n, rows_per_block):
        last = min(n, first + rows_per_block)
        x, y = np.meshgrid(coords, coords[first * s:last * s])
        col, row = project_points(h, x, y)
        yield first, last, col, row


def rectify(photo: np.ndarray, h: np.ndarray, resolution: int, half_width: float,
            supersample: int = 4) -> np.ndarray:
    """Receiver image (C, n, n), rows y-up, from ``photo`` (H, W) or (H, W, C) (row 0 = top).

    Each receiver pixel is the mean of supersample x supersample bilinear photo samples at the
    images under ``h`` (from :func:`homography`) of a uniform sub-grid of the pixel.
    """
    resolution, supersample = check_receiver_grid(resolution, half_width, supersample)
    photo = np.asarray(photo, dtype=np.float64)
    photo = photo[..., None] if photo.ndim == 2 else photo
    if photo.ndim != 3:
        raise ValueError(f"photo has shape {photo.shape}; expected (H, W) or (H, W, C)")
    s, n = supersample, resolution
    out = np.empty((photo.shape[2], n, n))
    for first, last, col, row in _receiver_blocks(np.asarray(h, dtype=np.float64), n, half_width, s):
        samples = np.moveaxis(bilinear_samples(photo, col, row), -1, 0)
        out[:, first:last] = samples.reshape(-1, last - first, s, n, s).mean(axis=(2, 4))
    return out


def saturated_receiver_pixels(saturated_photo_mask: np.ndarray, h: np.ndarray, resolution: int,
                              half_width: float, supersample: int = 4) -> np.ndarray:
    """(n, n) bool, rows y-up: receiver pixels any of whose sub-samples (as in :func:`rectify`)
    has a photo pixel of ``saturated_photo_mask`` (H, W) in its 2 x 2 bilinear support."""
    resolution, supersample = check_receiver_grid(resolution, half_width, supersample)
    mask = np.asarray(saturated_photo_mask, dtype=bool)
    if mask.ndim != 2:
        raise ValueError(f"saturated photo mask has shape {mask.shape}; expected (H, W)")
    touched = mask.copy()  # touched[r, c]: the support with top-left pixel (r, c) holds a marked pixel
    touched[:-1] |= mask[1:]
    touched[:, :-1] |= touched[:, 1:].copy()
    s, n = supersample, resolution
    out = np.empty((n, n), dtype=bool)
    for first, last, col, row in _receiver_blocks(np.asarray(h, dtype=np.float64), n, half_width, s):
        r0, c0, _, _ = _support(col, row, mask.shape)
        out[first:last] = touched[r0, c0].reshape(last - first, s, n, s).any(axis=(1, 3))
    return out


def inside_receiver(h: np.ndarray, shape: tuple[int, int], half_width: float) -> np.ndarray:
    """(H, W) bool: photo pixel centres whose receiver point lies in [-W, W]^2."""
    unit = np.array([[-1.0, 1.0, 1.0, -1.0], [-1.0, -1.0, 1.0, 1.0]])
    cols, rows = project_points(h, half_width * unit[0], half_width * unit[1])
    c0, r0 = max(0, int(np.ceil(cols.min()))), max(0, int(np.ceil(rows.min())))
    c1, r1 = min(shape[1] - 1, int(np.floor(cols.max()))), min(shape[0] - 1, int(np.floor(rows.max())))
    inside = np.zeros(shape, dtype=bool)
    row, col = np.ogrid[r0:r1 + 1, c0:c1 + 1]  # only the quadrilateral's bounding box
    x, y = project_points(np.linalg.inv(h), col.astype(np.float64), row.astype(np.float64))
    inside[r0:r1 + 1, c0:c1 + 1] = (np.abs(x) <= half_width) & (np.abs(y) <= half_width)
    return inside
