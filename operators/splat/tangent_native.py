"""The forward derivative of one photon's splat (:func:`operators.splat.native.splat_photon`):
the image's change when the photon's flux, position and footprint move along a tangent.

A photon deposits P_k = f w_k / s on pixel k, w_k = max(1 - t_k, 0)^2, t_k = r_k^T Q r_k,
r_k = pixel_k - (px, py), s = sum of w over the whole ellipse. Along a tangent
(df, dpx, dpy, dq00, dq01, dq11):

    dt_k = dq00 rx^2 + 2 dq01 rx ry + dq11 ry^2 - 2 (Q r_k) . (dpx, dpy),
    dw_k = -2 (1 - t_k) dt_k inside the ellipse (0 outside: w and its derivative vanish on the rim),
    dP_k = (df w_k + f (dw_k - w_k ds / s)) / s,  ds = sum of dw over the whole ellipse.

The tangent's order is that of the splat's gather (flux, px, py, q00, q01, q11), so the
reverse pass and this forward pass are one Jacobian and its transpose.
"""

from __future__ import annotations

from operators.kernels.numba_settings import jit_inline
from operators.splat.native import falloff, footprint_box, footprint_usable, row_terms

__all__ = ["splat_tangent"]


@jit_inline
def splat_tangent(img, c, px, py, q00, q01, q11, f, tangent, buf) -> None:
    """Add to channel ``c`` of ``img`` (c, n, n) the derivative of one photon's splat along
    ``tangent`` = (d flux, d px, d py, d q00, d q01, d q11), six floats. ``buf`` (2, capacity) holds the
    weights and their derivatives over the footprint's bounding box; a photon whose box has more
    pixels than that, or an unusable footprint, adds nothing (as :func:`splat_photon` leaves it out)."""
    if not footprint_usable(f, px, py, q00, q01, q11):
        return
    x0, x1, y0, y1 = footprint_box(px, py, q00, q01, q11)
    width, rows = x1 - x0 + 1, y1 - y0 + 1
    if width <= 0 or rows <= 0 or width * rows > buf.shape[1]:
        return
    d_f, d_px, d_py, d00, d01, d11 = tangent[0], tangent[1], tangent[2], tangent[3], tangent[4], tangent[5]
    s = ds = 0.0
    for r in range(rows):
        ry = y0 + r - py
        b, e = row_terms(q01, q11, ry)
        for j in range(width):
            rx = x0 + j - px
            u = max(falloff(q00, rx, b, e), 0.0)
            dt = (d00 * rx * rx + 2.0 * d01 * rx * ry + d11 * ry * ry
                  - 2.0 * ((q00 * rx + q01 * ry) * d_px + (q01 * rx + q11 * ry) * d_py))
            k = r * width + j
            buf[0, k] = u * u
            buf[1, k] = -2.0 * u * dt
            s += u * u
            ds += buf[1, k]
    if s <= 0.0:
        return
    n = img.shape[1]
    mean = ds / s
    for r in range(max(0, -y0), min(rows, n - y0)):
        row = img[c, y0 + r]
        for j in range(max(0, -x0), min(width, n - x0)):
            k = r * width + j
            row[x0 + j] += (d_f * buf[0, k] + f * (buf[1, k] - buf[0, k] * mean)) / s
