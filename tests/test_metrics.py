"""Metrics and transfer functions against hand-computed values; numpy and torch agree."""
import math

import numpy as np
import pytest
import torch

from mcdenoise.training import metrics as M
from mcdenoise.runtime import transfer as T


def test_smape_hand_computed():
    p = np.array([[[1.0, 0.0, 2.0]]])
    r = np.array([[[3.0, 0.0, 2.0]]])
    # |1-3|/(1+3+.01) = 2/4.01; 0/(0+0+.01) = 0; 0
    assert M.smape(p, r) == pytest.approx((2 / 4.01) / 3)


def test_smape_one_value():
    assert M.smape(np.array([1.0]), np.array([3.0])) == pytest.approx(2 / (4 + 0.01))
    assert M.smape(np.array([1.0]), np.array([3.0]), eps=0.0) == pytest.approx(0.5)


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


def _tonemap_inverse(t):
    """Radiance x with reinhard_gamma(x) == t."""
    q = t ** T.REINHARD_GAMMA
    return q / (1 - q)


def test_psnr_from_known_mse():
    # Tonemapped pred is 0.5 everywhere, ref 0: mse 0.25 -> 10 log10(4) dB, over a stack too.
    p = np.full((2, 3, 4, 3), _tonemap_inverse(0.5))
    assert T.reinhard_gamma(p)[0, 0, 0, 0] == pytest.approx(0.5)
    assert M.mse_tonemapped(p, np.zeros_like(p)) == pytest.approx(0.25)
    assert M.psnr(p, np.zeros_like(p)) == pytest.approx(10 * math.log10(4))


def test_trmae_hand_computed():
    # ANF Eq. 16: 1/3 E_xyt[ ||dO - dO*||_1 / (||dO*||_1 + eps) ], L1 over the channels.
    ref = np.zeros((2, 1, 1, 3))
    ref[1] = 1.0
    pred = np.zeros((2, 1, 1, 3))
    pred[1] = 0.5
    # ||(-0.5, -0.5, -0.5)||_1 = 1.5 over ||(1, 1, 1)||_1 + 0.01 = 3.01, times 1/3
    assert M.trmae(pred, ref) == pytest.approx(1.5 / 3.01 / 3)
    with pytest.raises(ValueError, match="T>=2"):
        M.trmae(pred[:1], ref[:1])


def test_trmae_two_pixels_three_frames():
    ref = np.zeros((3, 1, 2, 3))
    pred = np.zeros((3, 1, 2, 3))
    ref[1, 0, 0] = (2.0, 0.0, 0.0)  # pixel 0: ref jumps up then back, pred stays
    pred[:, 0, 1] = [[0, 0, 0], [0, 1, 0], [0, 1, 0]]  # pixel 1: pred flickers once, ref static
    # pixel 0: t=1 |2|/(2+.01), t=2 |2|/(2+.01); pixel 1: t=1 1/(0+.01), t=2 0
    expected = (2 / 2.01 + 2 / 2.01 + 1 / 0.01 + 0) / 4 / 3
    assert M.trmae(pred, ref) == pytest.approx(expected)
    assert M.trmae(ref, ref) == 0.0


def _ssim_brute_force(x, y):
    """Independent SSIM: per channel, per window position, weighted statistics in a loop."""
    k, sigma = 11, 1.5
    ax = np.arange(k) - 5.0
    g2 = np.exp(-(ax[:, None] ** 2 + ax[None, :] ** 2) / (2 * sigma ** 2))
    g2 /= g2.sum()
    tx, ty = T.reinhard_gamma(x), T.reinhard_gamma(y)
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    vals = []
    for c in range(3):
        for i in range(x.shape[0] - k + 1):
            for j in range(x.shape[1] - k + 1):
                a = tx[i:i + k, j:j + k, c]
                b = ty[i:i + k, j:j + k, c]
                ma, mb = (g2 * a).sum(), (g2 * b).sum()
                va = (g2 * (a - ma) ** 2).sum()
                vb = (g2 * (b - mb) ** 2).sum()
                cov = (g2 * (a - ma) * (b - mb)).sum()
                vals.append((2 * ma * mb + c1) * (2 * cov + c2) / ((ma ** 2 + mb ** 2 + c1) * (va + vb + c2)))
    return float(np.mean(vals))


def test_ssim_identical_is_one_and_constant_images_reduce_to_luminance_term():
    rng = np.random.default_rng(1)
    x = rng.random((16, 13, 3)) * 4
    assert M.ssim(x, x) == pytest.approx(1.0, abs=1e-12)
    # Constant images: variances and covariance are 0, so SSIM = (2ab + C1) / (a^2 + b^2 + C1)
    # with a, b the tonemapped values.
    a, b = 0.3, 0.6
    pa = np.full((12, 12, 3), _tonemap_inverse(a))
    pb = np.full((12, 12, 3), _tonemap_inverse(b))
    c1 = 0.01 ** 2
    assert M.ssim(pa, pb) == pytest.approx((2 * a * b + c1) / (a * a + b * b + c1), rel=1e-9)


def test_ssim_matches_brute_force_windows_and_averages_frames():
    rng = np.random.default_rng(2)
    x = rng.random((15, 17, 3)) * 2
    y = np.clip(x + 0.3 * rng.standard_normal(x.shape), 0, None)
    want = _ssim_brute_force(x, y)
    assert 0.2 < want < 0.99
    assert M.ssim(x, y) == pytest.approx(want, rel=1e-10)
    # A stack is the mean over frames (all frames have the same number of windows).
    assert M.ssim(np.stack([x, x]), np.stack([y, x])) == pytest.approx((want + 1) / 2, rel=1e-10)


def test_ssim_and_flip_reject_bad_shapes():
    with pytest.raises(ValueError, match="at least 11x11"):
        M.ssim(np.zeros((10, 20, 3)), np.zeros((10, 20, 3)))
    for fn in (M.ssim, M.flip):
        with pytest.raises(ValueError, match="same shape"):
            fn(np.zeros((16, 16, 3)), np.zeros((16, 17, 3)))
        with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
            fn(np.zeros((16, 16)), np.zeros((16, 16)))


def test_flip_zero_when_identical_and_monotone_in_noise():
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:48, 0:48] / 48.0
    ref = np.stack([xx, yy, 0.5 * (xx + yy)], axis=-1) * 3.0
    assert M.flip(ref, ref) == 0.0
    noise = rng.standard_normal(ref.shape)
    errs = [M.flip(np.clip(ref * (1 + s * noise), 0, None), ref) for s in (0.05, 0.2, 0.8)]
    assert errs[0] > 0.01
    assert errs[0] < errs[1] < errs[2] <= 1.0
    # Stacks: mean over frames; non-finite input is scored, not passed to FLIP.
    noisy = np.clip(ref * (1 + 0.2 * noise), 0, None)
    assert M.flip(np.stack([ref, noisy]), np.stack([ref, ref])) == pytest.approx(errs[1] / 2, rel=1e-6)
    bad = ref.copy()
    bad[0, 0] = np.nan
    bad[1, 1] = np.inf
    assert 0.0 < M.flip(bad, ref) < errs[0]


def test_flip_without_package_says_how_to_install(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "flip_evaluator", None)
    with pytest.raises(ImportError, match="pip install flip-evaluator"):
        M.flip(np.zeros((16, 16, 3)), np.zeros((16, 16, 3)))


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


def _moving_plane(t_len=4, h=12, w=16, seed=0):
    """Frames of a textured plane sliding one pixel right per frame (exact integer motion),
    with a reference = texture + small render noise."""
    from mcdenoise.runtime.frames import Frame

    rng = np.random.default_rng(seed)
    tex = rng.random((h, w + t_len, 3)).astype(np.float32) + 0.5
    frames = []
    for t in range(t_len):
        u = np.arange(w)[None, :] - t + t_len                 # texture column seen at pixel x
        clean = tex[:, u[0]]
        pos = np.stack([np.broadcast_to(u, (h, w)), np.broadcast_to(np.arange(h)[:, None], (h, w)),
                        np.full((h, w), 10.0)], -1).astype(np.float32)
        motion = np.zeros((h, w, 2), np.float32)
        motion[..., 0] = -1.0                                  # pixel x showed at x - 1 in t - 1
        valid = np.ones((h, w, 1), np.float32)
        valid[:, 0] = 0.0
        if t == 0:
            valid[:] = 0.0
        nrm = np.zeros((h, w, 3), np.float32)
        nrm[..., 2] = -1.0
        ref = clean * (1 + 0.02 * rng.standard_normal(clean.shape).astype(np.float32))
        frames.append(Frame(color=ref, albedo=np.ones_like(ref), normal=nrm, depth=np.full((h, w, 1), 10.0, np.float32),
                            position=pos, motion=motion, valid=valid, reference=ref, meta={}))
    return frames, np.stack([tex[:, np.arange(w) - t + t_len] for t in range(t_len)])


def test_warped_temporal_error_separates_flicker_from_steadiness():
    frames, clean = _moving_plane()
    refs = np.stack([f.reference for f in frames])
    rng = np.random.default_rng(1)
    assert M.warped_temporal_error(refs, refs, frames) == pytest.approx(1.0)
    flicker = refs * (1 + 0.2 * rng.standard_normal(refs.shape).astype(np.float32))
    assert M.warped_temporal_error(flicker, refs, frames) > 3.0
    # The clean texture moving with the plane: steadier along the motion than the reference's
    # render noise (an exact integer warp leaves no error at all).
    p, r = M.warped_error_sums(clean, refs, frames)
    assert r > 0 and p < 1e-6 * r
    # One frame, or frames without motion: nothing to warp.
    assert M.warped_temporal_error(refs[:1], refs[:1], frames[:1]) is None
