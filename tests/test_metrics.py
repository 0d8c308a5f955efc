"""Metrics and transfer functions against hand-computed values; numpy and torch agree."""
import math

import numpy as np
import pytest
import torch

from runtime import metrics as M
from runtime import transfer as T


def test_smape_hand_computed():
    p = np.array([[[1.0, 0.0, 2.0]]])
    r = np.array([[[3.0, 0.0, 2.0]]])
    # |1-3|/(1+3+.01) = 2/4.01; 0/(0+0+.01) = 0; 0
    assert M.smape(p, r) == pytest.approx((2 / 4.01) / 3)


def test_relmse_hand_computed():
    p, r = np.array([2.0, 1.0]), np.array([1.0, 1.0])
    assert M.relmse(p, r) == pytest.approx(((1 / 1.01) + 0) / 2)


def test_psnr_hand_computed():
    # tau(1) = (1/2)^(1/2.4); tau(0) = 0 -> mse = tau(1)^2 over 1 of 3 channels.
    p = np.array([[[1.0, 0.0, 0.0]]])
    r = np.zeros_like(p)
    tau1 = 0.5 ** (1 / 2.4)
    assert M.psnr(p, r) == pytest.approx(-10 * math.log10(tau1 ** 2 / 3), rel=1e-6)
    assert M.psnr(r, r) == float("inf")


def test_trmae_hand_computed():
    ref = np.zeros((2, 1, 1, 3))
    ref[1] = 1.0
    pred = np.zeros((2, 1, 1, 3))
    pred[1] = 0.5
    # |0.5 - 1| / (1 + 0.01) per element
    assert M.trmae(pred, ref) == pytest.approx(0.5 / 1.01)
    with pytest.raises(ValueError, match="T>=2"):
        M.trmae(pred[:1], ref[:1])


def test_numpy_and_torch_agree_and_torch_has_gradients():
    rng = np.random.default_rng(0)
    a, b = rng.random((4, 5, 3)) * 3, rng.random((4, 5, 3)) * 3
    ta = torch.tensor(a, requires_grad=True)
    tb = torch.tensor(b)
    for fn in (M.smape, M.relmse):
        assert float(fn(ta, tb).detach()) == pytest.approx(fn(a, b), rel=1e-9)
    M.smape(ta, tb).backward()
    assert ta.grad is not None and torch.isfinite(ta.grad).all()
    for name in T.TRANSFERS:
        np.testing.assert_allclose(T.get(name)(torch.tensor(a)).numpy(), T.get(name)(a), rtol=1e-6)


def test_transfer_inverses_and_ranges():
    x = np.linspace(0, 1, 11)
    np.testing.assert_allclose(T.gamma_inv(T.gamma(x)), x, atol=1e-6)
    y = np.array([0.0, 0.5, 10.0, 1e4])
    np.testing.assert_allclose(T.log1p_inv(T.log1p(y)), y, rtol=1e-9)
    assert T.gamma(np.array([5.0]))[0] == pytest.approx(1.0)
    assert T.log1p(np.array([-3.0]))[0] == 0.0
    assert 0 <= T.reinhard_gamma(np.array([1e9]))[0] < 1.0
    with pytest.raises(KeyError, match="unknown transfer function 'srgbx'"):
        T.get("srgbx")
