"""Gradients of the full operator against central finite differences (fixed random numbers)."""

from __future__ import annotations

import torch

from tests.operators.conftest import bump, make_operator


def directional_check(op, heights, weights, seed=0, eps=1e-6):
    direction = torch.randn(heights.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(seed))
    direction = direction * (heights > 1e-3)  # stay inside d >= 0
    grad = op.vjp(heights, weights)

    def loss(d):
        return float((op.render(d) * weights).sum())

    numeric = (loss(heights + eps * direction) - loss(heights - eps * direction)) / (2 * eps)
    analytic = float((grad * direction).sum())
    return numeric, analytic


def test_operator_gradient_matches_finite_differences_on_a_smooth_field():
    op = make_operator(photons=20_000, resolution=32)
    heights = bump(16, (0.1, -0.15), 0.35, 0.06) + 0.01
    weights = torch.randn(op.output_shape, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    for seed in range(3):
        numeric, analytic = directional_check(op, heights, weights, seed)
        assert abs(numeric - analytic) <= 2e-5 * abs(analytic), (numeric, analytic)


def test_loss_and_grad_is_the_gradient_of_the_squared_loss_and_independent_of_chunking():
    heights = bump(16, height=0.05) + 0.005
    target = make_operator(photons=20_000, resolution=32, seed=7).render(bump(16, height=0.04))
    results = [make_operator(photons=20_000, resolution=32, chunk_size=c).loss_and_grad(heights, target)
               for c in (3_000, 1 << 18)]
    (loss_a, grad_a, image_a), (loss_b, grad_b, _) = results
    assert abs(loss_a - loss_b) <= 1e-12 * loss_b
    assert torch.allclose(grad_a, grad_b, rtol=1e-9, atol=1e-12 * float(grad_b.abs().max()))
    assert abs(loss_a - 0.5 * float(((image_a - target) ** 2).sum())) <= 1e-12 * loss_a
    op = make_operator(photons=20_000, resolution=32)
    leaf = heights.clone().requires_grad_(True)
    (0.5 * ((op(leaf) - target) ** 2).sum()).backward()
    assert torch.allclose(leaf.grad, grad_a, rtol=1e-9, atol=1e-12 * float(grad_a.abs().max()))
    # A rendered image handed in (a line search's accepted trial) gives the same loss and gradient.
    loss_c, grad_c, image_c = op.loss_and_grad(heights, target, image=op.render(heights))
    assert abs(loss_c - loss_a) <= 1e-12 * loss_a and torch.equal(image_c, op.render(heights))
    assert torch.allclose(grad_c, grad_a, rtol=1e-9, atol=1e-12 * float(grad_a.abs().max()))


def test_gradient_stays_finite_when_steep_lines_and_absorbing_walls_lose_photons():
    op = make_operator(photons=50_000, resolution=32, dtype="float32", walls="absorbing")
    axis = torch.linspace(-1, 1, 64)
    ridge = 0.08 * torch.exp(-axis ** 2 / (2 * 0.02 ** 2))  # slopes up to ~2.4: beyond the critical angle
    heights = ridge.expand(64, 64).contiguous()
    _, metric, flux, _ = op.splat_inputs(heights, 0, op.photons)
    assert int((flux == 0).sum()) > 0 and bool(torch.isfinite(metric).all())
    loss, grad, _ = op.loss_and_grad(heights, op.render(torch.zeros(64, 64)))
    assert loss > 0 and bool(torch.isfinite(grad).all()) and float(grad.abs().max()) > 0
