"""Orthogonal DWT: perfect reconstruction, adjoint (dot) tests, and the wavelet L1 prox."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.optimize import minimize

from regularizers import WaveletL1, WaveletTransform

CASES = [((128, 128), "db3", 3), ((32, 32), "db3", 2), ((16, 8), "haar", 1)]


def dot(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a * b).sum())


@pytest.mark.parametrize("shape, wavelet, levels", CASES)
def test_perfect_reconstruction_and_orthogonality(shape, wavelet, levels, rng: np.random.Generator) -> None:
    W = WaveletTransform(shape, wavelet, levels)
    x = torch.from_numpy(rng.normal(size=shape))
    w = W.forward(x)
    assert w.shape == (shape[0] * shape[1],) and W.size == x.numel()
    torch.testing.assert_close(W.inverse(w), x, rtol=0, atol=1e-12)
    assert float(w.norm()) == pytest.approx(float(x.norm()), rel=1e-12)


@pytest.mark.parametrize("shape, wavelet, levels", CASES)
def test_adjoint_identities(shape, wavelet, levels, rng: np.random.Generator) -> None:
    """<W x, y> = <x, W^* y> and <W^-1 y, x> = <y, (W^-1)^* x> on random data."""
    W = WaveletTransform(shape, wavelet, levels)
    x = torch.from_numpy(rng.normal(size=shape))
    y = torch.from_numpy(rng.normal(size=shape[0] * shape[1]))
    lhs, rhs = dot(W.forward(x), y), dot(x, W.forward_adjoint(y))
    assert lhs == pytest.approx(rhs, rel=1e-12, abs=1e-12)
    lhs, rhs = dot(W.inverse(y), x), dot(y, W.inverse_adjoint(x))
    assert lhs == pytest.approx(rhs, rel=1e-12, abs=1e-12)


def test_dtype_and_device_are_preserved(device: torch.device) -> None:
    W = WaveletTransform((32, 32), "db3", 2)
    x = torch.rand(32, 32, dtype=torch.float32, device=device)
    w = W.forward(x)
    assert w.dtype == torch.float32 and w.device == x.device
    back = W.inverse(w)
    assert back.dtype == torch.float32 and back.device == x.device
    torch.testing.assert_close(back, x, rtol=0, atol=1e-5)


def test_wavelet_l1_value_and_coefficient_prox() -> None:
    reg = WaveletL1(alpha_w=0.5, wavelet="haar", levels=1)
    d = torch.zeros(2, 2, dtype=torch.float64)
    d[0, 0] = 2.0  # haar, one level: all four coefficients are +-1
    assert reg.value(d) == pytest.approx(0.5 * 4.0)
    w = torch.tensor([-1.0, 0.1, 0.3, 2.0], dtype=torch.float64)
    torch.testing.assert_close(reg.prox_coefficients(w, 0.4), torch.tensor([-0.8, 0.0, 0.1, 1.8], dtype=torch.float64))


def test_wavelet_l1_prox_matches_constrained_brute_force(rng: np.random.Generator) -> None:
    """min_x t a ||W x||_1 + 1/2||x - w||^2 solved as a smooth program with s >= |W x| (W as a dense matrix)."""
    shape, alpha, step = (4, 4), 0.3, 0.5
    reg = WaveletL1(alpha, wavelet="haar", levels=1)
    W = reg.transform_for(shape)
    n = 16
    matrix = np.stack([W.forward(torch.eye(n, dtype=torch.float64)[i].reshape(shape)).numpy() for i in range(n)], 1)
    w = rng.normal(size=n)

    def objective(z: np.ndarray) -> float:
        x, s = z[:n], z[n:]
        return step * alpha * s.sum() + 0.5 * np.sum((x - w) ** 2)

    def gradient(z: np.ndarray) -> np.ndarray:
        return np.concatenate([z[:n] - w, np.full(n, step * alpha)])

    cons = [
        {"type": "ineq", "fun": lambda z: z[n:] - matrix @ z[:n], "jac": lambda z: np.hstack([-matrix, np.eye(n)])},
        {"type": "ineq", "fun": lambda z: z[n:] + matrix @ z[:n], "jac": lambda z: np.hstack([matrix, np.eye(n)])},
    ]
    z0 = np.concatenate([w, np.abs(matrix @ w)])
    options = {"ftol": 1e-14, "maxiter": 500}
    res = minimize(objective, z0, jac=gradient, constraints=cons, method="SLSQP", options=options)
    assert res.success, res.message
    got = reg.prox(torch.from_numpy(w.reshape(shape)), step).numpy().ravel()
    np.testing.assert_allclose(got, res.x[:n], atol=1e-6)


def test_wavelet_l1_moreau_identity(rng: np.random.Generator) -> None:
    """f*(y) = indicator{||W y||_inf <= alpha}: y = (w - p)/t must satisfy it and f(p) = <p, y>."""
    alpha, step = 0.05, 0.8
    reg = WaveletL1(alpha)  # db3, 3 levels
    w = torch.from_numpy(rng.normal(size=(64, 64)))
    p = reg.prox(w, step)
    y = (w - p) / step
    assert float(reg.transform_for((64, 64)).forward(y).abs().max()) <= alpha * (1 + 1e-10)
    assert reg.value(p) == pytest.approx(dot(p, y), rel=1e-10)


def test_subbands_partition_the_coefficients_and_each_centre_sits_in_its_band() -> None:
    transform = WaveletTransform((32, 32), "db3", 3)
    bands = transform.subbands()
    assert len(bands) == 1 + 3 * 3
    masks = torch.stack([mask for mask, _ in bands])
    assert bool((masks.sum(0) == 1).all())  # every coefficient in exactly one subband
    assert [int(mask.sum()) for mask, _ in bands] == [16] + [16] * 3 + [64] * 3 + [256] * 3
    assert all(bool(mask[centre]) for mask, centre in bands)
    # each middle coefficient's basis function peaks a quarter of the grid or more from the border
    for _, centre in bands:
        basis = torch.zeros(32 * 32, dtype=torch.float64)
        basis[centre] = 1.0
        ys, xs = np.unravel_index(int(transform.inverse(basis).abs().argmax()), (32, 32))
        assert 8 <= ys <= 24 and 8 <= xs <= 24, (centre, ys, xs)


def test_weighted_coefficient_prox_shrinks_each_coefficient_by_its_own_threshold() -> None:
    prior = WaveletL1(alpha_w=0.5)
    w = torch.tensor([2.0, -2.0, 0.3, 1.0], dtype=torch.float64)
    metric = torch.tensor([1.0, 0.5, 1.0, 4.0], dtype=torch.float64)
    out = prior.prox_coefficients(w, 0.8, metric)  # thresholds 0.4, 0.2, 0.4, 1.6
    torch.testing.assert_close(out, torch.tensor([1.6, -1.8, 0.0, 0.0], dtype=torch.float64))
