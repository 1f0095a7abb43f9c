"""The native splat against the straightforward PyTorch splat, its adjoint and its derivatives."""

from __future__ import annotations

import numpy as np
import torch

from operators.splat.splat import PAD_STEP, PaddedAdjoint, footprint_metric, splat_photons
from operators.splat.reference import splat_photons_reference
from operators.splat.native import pad_for_gather


def random_photons(count: int = 300, resolution: int = 24, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    pos = torch.rand(2, count, generator=g, dtype=torch.float64) * (resolution + 6) - 3
    footprint = torch.randn(2, 2, count, generator=g, dtype=torch.float64) * 2.0
    metric = footprint_metric(footprint, 1.0, 6.0)
    flux = torch.rand(count, generator=g, dtype=torch.float64) + 0.1
    channel = torch.randint(0, 2, (count,), generator=g)
    return pos, metric, flux, channel


def test_native_splat_equals_reference_splat():
    pos, metric, flux, channel = random_photons()
    native = splat_photons(pos, metric, flux, channel, 2, 24)
    reference = splat_photons_reference(pos, metric, flux, channel, 2, 24)
    assert torch.allclose(native, reference, rtol=1e-10, atol=1e-12)


def test_each_photon_deposits_its_flux_when_fully_on_the_image():
    pos, metric, flux, channel = random_photons()
    pos = pos.clamp(8, 16)
    image = splat_photons(pos, metric, flux, channel, 2, 24)
    assert torch.allclose(image.sum(), flux.sum(), rtol=1e-12)


def test_adjoint_identity_for_flux():
    pos, metric, flux, channel = random_photons(seed=1)
    g = torch.randn(2, 24, 24, dtype=torch.float64, generator=torch.Generator().manual_seed(5))
    f = flux.clone().requires_grad_(True)
    image = splat_photons(pos, metric, f, channel, 2, 24)
    (grad,) = torch.autograd.grad(image, f, g)
    # splat is linear in flux: <S phi, g> = <phi, S^* g>
    assert torch.allclose((image * g).sum(), (flux * grad).sum(), rtol=1e-12)


def test_position_and_metric_gradients_match_finite_differences():
    pos, metric, flux, channel = random_photons(count=60, seed=2)
    g = torch.randn(2, 24, 24, dtype=torch.float64, generator=torch.Generator().manual_seed(7))
    p = pos.clone().requires_grad_(True)
    q = metric.clone().requires_grad_(True)
    loss = (splat_photons(p, q, flux, channel, 2, 24) * g).sum()
    grad_p, grad_q = torch.autograd.grad(loss, (p, q))
    eps = 1e-6
    for tensor, grad in ((pos, grad_p), (metric, grad_q)):
        direction = torch.randn(tensor.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(3))
        if tensor is metric:
            direction = direction * metric.abs() * 0.1  # keep the ellipses valid
        plus = (splat_photons(pos + eps * direction if tensor is pos else pos,
                              metric + eps * direction if tensor is metric else metric,
                              flux, channel, 2, 24) * g).sum()
        minus = (splat_photons(pos - eps * direction if tensor is pos else pos,
                               metric - eps * direction if tensor is metric else metric,
                               flux, channel, 2, 24) * g).sum()
        numeric = (plus - minus) / (2 * eps)
        analytic = (grad * direction).sum()
        assert abs(float(numeric - analytic)) <= 1e-6 * max(1.0, abs(float(analytic))), (numeric, analytic)


def native_and_reference_gradients(pos, metric, flux, channel, g):
    """Gradients of <splat, g> w.r.t. (pos, metric, flux) by the native and the reference splat."""
    grads = []
    for splat in (splat_photons, splat_photons_reference):
        leaves = [t.clone().requires_grad_(True) for t in (pos, metric, flux)]
        loss = (splat(*leaves, channel, g.shape[0], g.shape[1]) * g).sum()
        grads.append(torch.autograd.grad(loss, leaves))
    return grads


def test_native_and_reference_gradients_agree():
    pos, metric, flux, channel = random_photons(count=80, seed=4)
    g = torch.randn(2, 24, 24, dtype=torch.float64, generator=torch.Generator().manual_seed(9))
    for native, reference in zip(*native_and_reference_gradients(pos, metric, flux, channel, g)):
        assert torch.allclose(native, reference, rtol=1e-8, atol=1e-10)


def test_gather_handles_photons_wider_than_the_image_and_far_off_it():
    """The padded gather: footprints larger than the 24 px image and photons whose footprint
    misses the image entirely (their gradients are exactly zero)."""
    pos = torch.tensor([[12.0, -30.0, 10.0, 60.0], [11.5, 12.0, 35.0, 60.0]], dtype=torch.float64)
    footprint = torch.tensor([[[30.0, 3.0, 4.0, 2.0], [5.0, 1.0, 0.0, 0.0]],
                              [[-4.0, 0.5, 0.0, 0.0], [20.0, 2.0, 4.0, 2.0]]], dtype=torch.float64)
    metric = footprint_metric(footprint, 1.0, 40.0)
    flux = torch.tensor([1.0, 2.0, 0.5, 3.0], dtype=torch.float64)
    channel = torch.zeros(4, dtype=torch.int64)
    g = torch.randn(1, 24, 24, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    grads = native_and_reference_gradients(pos, metric, flux, channel, g)
    for native, reference in zip(*grads):
        assert torch.allclose(native, reference, rtol=1e-9, atol=1e-12)
    assert all(float(t[..., 1:].abs().max()) == 0.0 for t in grads[0])  # photons 2-4 miss the image
    assert float(grads[0][2][0].abs()) > 0.0


def test_footprint_metric_is_the_inverse_covariance_with_pixel_filter_and_cut_off():
    du = torch.tensor([[3.0], [0.0]], dtype=torch.float64)
    dv = torch.tensor([[0.0], [0.5]], dtype=torch.float64)
    q = footprint_metric(torch.stack([du, dv]), 1.0, 20.0)[:, 0]
    assert torch.allclose(q, torch.tensor([1 / 10.0, 0.0, 1 / 1.25], dtype=torch.float64))
    big = footprint_metric(torch.stack([du * 100, dv]), 1.0, 20.0)[:, 0]
    major_axis = (1.0 / big[0]).sqrt()
    assert abs(float(major_axis) - 20.0) < 1e-9


def test_nearly_degenerate_huge_footprint_gives_a_finite_well_shaped_ellipse():
    # A rank-1 footprint of ~4e5 px (a photon near a focal line on a steep flank), in float32.
    footprint = torch.tensor([[[2958.4 * 128], [482.1146 * 128]], [[521.2621 * 128], [85.1678 * 128]]])
    q = footprint_metric(footprint, 1.0, 20.0)[:, 0].double()
    assert bool(torch.isfinite(q).all())
    eig = torch.linalg.eigvalsh(torch.tensor([[q[0], q[1]], [q[1], q[2]]]))
    semi_axes = 1.0 / eig.sqrt()
    assert abs(float(semi_axes.max()) - 20.0) < 1e-3 and abs(float(semi_axes.min()) - 1.0) < 1e-3


def test_fixed_box_and_general_paths_agree_with_the_reference():
    """Footprints whose bounding box fits the fixed LANES x LANES box (the vectorised path) and
    those that do not (wider, or at the image border) splat and gather as the reference does."""
    from operators.splat.native import footprint_box, _fits_fixed_box

    g = torch.Generator().manual_seed(11)
    count, n = 200, 32
    radius = torch.rand(count, generator=g, dtype=torch.float64) * 4.0 + 1.5  # half extents 1.5 .. 5.5 px
    pos = torch.rand(2, count, generator=g, dtype=torch.float64) * (n + 4) - 2
    metric = torch.stack([radius ** -2, torch.zeros(count, dtype=torch.float64), radius ** -2])
    flux = torch.rand(count, generator=g, dtype=torch.float64) + 0.1
    channel = torch.zeros(count, dtype=torch.int64)
    fits = [
        _fits_fixed_box(*footprint_box(*pos[:, k].tolist(), *metric[:, k].tolist()), 0, n - 1) for k in range(count)
    ]
    assert 40 <= sum(fits) <= count - 40, sum(fits)  # both paths taken
    native = splat_photons(pos, metric, flux, channel, 1, n)
    reference = splat_photons_reference(pos, metric, flux, channel, 1, n)
    assert torch.allclose(native, reference, rtol=1e-10, atol=1e-12)
    image_grad = torch.randn(1, n, n, dtype=torch.float64, generator=g)
    for native_grad, reference_grad in zip(*native_and_reference_gradients(pos, metric, flux, channel, image_grad)):
        assert torch.allclose(native_grad, reference_grad, rtol=1e-8, atol=1e-10)


def test_a_reused_padded_adjoint_equals_a_fresh_one():
    # The gradients pad the adjoint image into the buffer of the last gradient: the same values
    # as a new zero-bordered array, G / divisor computed as float64 from float32 pixels.
    rng = np.random.default_rng(0)
    first, second = (rng.standard_normal((2, 40, 40)).astype(np.float32) for _ in range(2))
    buffer = pad_for_gather(first, 7, 3.0)
    reused = pad_for_gather(second, 7, 3.0, reuse=buffer)
    assert reused is buffer
    expected = np.zeros((2, 54, 54))
    expected[:, 7:47, 7:47] = second.astype(np.float64) / 3.0
    assert np.array_equal(reused, expected)
    assert pad_for_gather(second, 9, reuse=buffer) is not buffer  # another pad: a new array


def test_a_gradient_gathers_through_a_spare_buffer_as_through_its_own():
    pos, metric, flux, channel = (t.numpy() for t in random_photons(count=400))
    grad_image = np.random.default_rng(1).standard_normal((2, 24, 24))
    own = PaddedAdjoint(grad_image)
    expected = own.gather(pos, metric, flux, channel)
    assert own.pad % PAD_STEP == 0
    spare = np.full_like(own.padded, 0.0)
    reused = PaddedAdjoint(grad_image, spare=(spare, own.pad))
    for got, want in zip(reused.gather(pos, metric, flux, channel), expected):
        assert np.array_equal(got, want)
    assert reused.padded is spare
    # A spare of another border is left alone: the border follows from these photons only.
    wider = np.zeros((2, 24 + 2 * (own.pad + PAD_STEP), 24 + 2 * (own.pad + PAD_STEP)))
    other = PaddedAdjoint(grad_image, spare=(wider, own.pad + PAD_STEP))
    for got, want in zip(other.gather(pos, metric, flux, channel), expected):
        assert np.array_equal(got, want)
    assert other.padded is not wider and other.pad == own.pad
