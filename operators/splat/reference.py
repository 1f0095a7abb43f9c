"""A straightforward PyTorch splat: every (photon, footprint pixel) pair materialised at once.

Same mathematics as :mod:`operators.splat.native` (normalised Silverman weights); it exists as
an independent check of the native kernel and as the baseline that ``sfc-bench`` compares with.
Its memory grows with photons x footprint pixels: use it on small inputs only.
"""

from __future__ import annotations

import torch


def splat_photons_reference(pos: torch.Tensor, metric: torch.Tensor, flux: torch.Tensor,
                            channel: torch.Tensor, channels: int, resolution: int) -> torch.Tensor:
    """Same contract as :func:`operators.splat.splat.splat_photons`, differentiable by autograd."""
    q00, q01, q11 = metric
    det = q00 * q11 - q01 ** 2
    half_x = torch.sqrt(q11 / det).detach()
    half_y = torch.sqrt(q00 / det).detach()
    x0 = torch.ceil(pos[0].detach() - half_x).long()
    y0 = torch.ceil(pos[1].detach() - half_y).long()
    width = torch.floor(pos[0].detach() + half_x).long() - x0 + 1
    height = torch.floor(pos[1].detach() + half_y).long() - y0 + 1
    count = (width * height).clamp(min=0)
    photon = torch.repeat_interleave(torch.arange(len(flux)), count)
    start = torch.cumsum(count, 0) - count
    local = torch.arange(len(photon)) - start[photon]
    ix = x0[photon] + local % width[photon]
    iy = y0[photon] + local // width[photon]
    rx = ix.to(pos.dtype) - pos[0][photon]
    ry = iy.to(pos.dtype) - pos[1][photon]
    t = q00[photon] * rx ** 2 + 2 * q01[photon] * rx * ry + q11[photon] * ry ** 2
    w = torch.where(t < 1, (1 - t).clamp(min=0) ** 2, torch.zeros_like(t))
    norm = torch.zeros_like(flux).index_add(0, photon, w)
    value = w * (flux / torch.where(norm > 0, norm, torch.ones_like(norm)))[photon]
    on = (ix >= 0) & (ix < resolution) & (iy >= 0) & (iy < resolution)
    flat = (channel[photon] * resolution + iy) * resolution + ix
    image = torch.zeros(channels * resolution * resolution, dtype=flux.dtype, device=flux.device)
    image = image.index_add(0, flat[on], value[on])
    return image.view(channels, resolution, resolution)
