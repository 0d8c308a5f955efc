"""Image-quality metrics: the one definition used by training, bench and tests.

Inputs are linear HDR radiance.  :func:`smape`, :func:`relmse`, :func:`mse_tonemapped` and
:func:`psnr` take numpy arrays or torch tensors (same namespace for both arguments) with the
channel axis last for numpy ``(..., H, W, 3)`` or anywhere for torch, and reduce over all
elements; torch input keeps gradients (losses use these too).  :func:`ssim`, :func:`flip` and
:func:`trmae` are numpy only (evaluation metrics, no gradients), on ``(H, W, 3)`` images or
``(T, H, W, 3)`` stacks.

Which domain each metric sees, as the papers state it: SMAPE and relMSE on linear radiance
(eps = 0.01, WSKPN Eq. 6 / NDLE Eq. 9, NDLE Table 1); PSNR and SSIM on radiance tonemapped by
ANF Eq. 15 (:func:`runtime.transfer.reinhard_gamma`), as ANF Eq. 14 and NDLE Table 1; FLIP on
the same tonemapped images (see :func:`flip`); TRMAE on linear radiance (ANF Eq. 16).
"""
from __future__ import annotations

import math

import numpy as np

from mcdenoise.runtime.transfer import reinhard_gamma, xp

#: epsilon of SMAPE (WSKPN Eq. 6, Vogels et al. 2018) and relMSE / TRMAE (ANF Eq. 16).
SMAPE_EPS = 0.01
RELMSE_EPS = 0.01
TRMAE_EPS = 0.01


def _mean(x):
    return x.mean()


def pixels(frames) -> np.ndarray:
    """Every pixel of a list of (H, W, 3) frames of any sizes as one (P, 3) array: the
    per-pixel metrics (PSNR, SMAPE, relMSE) of it pool frames as one size's stack does."""
    return np.concatenate([np.asarray(f).reshape(-1, 3) for f in frames])


def smape(pred, ref, eps: float = SMAPE_EPS):
    """WSKPN Eq. 6: mean of |p - r| / (|p| + |r| + eps) over pixels and channels. Range [0, 1]."""
    if xp(pred) is np:
        return float(np.mean(np.abs(pred - ref) / (np.abs(pred) + np.abs(ref) + eps)))
    return _mean((pred - ref).abs() / (pred.abs() + ref.abs() + eps))


def relmse(pred, ref, eps: float = RELMSE_EPS):
    """Relative MSE: mean of (p - r)^2 / (r^2 + eps) (Rousselle et al.; eps as in ANF)."""
    if xp(pred) is np:
        return float(np.mean((pred - ref) ** 2 / (ref ** 2 + eps)))
    return _mean((pred - ref) ** 2 / (ref ** 2 + eps))


def mse_tonemapped(pred, ref):
    """Mean squared error after ANF Eq. 15's tonemapping (Reinhard + gamma 2.4)."""
    d = reinhard_gamma(pred) - reinhard_gamma(ref)
    return float(np.mean(d * d)) if xp(pred) is np else _mean(d * d)


def psnr(pred, ref) -> float:
    """ANF Eq. 14: PSNR in dB on tonemapped radiance (peak 1).  Over all pixels (and frames
    if the arrays hold several), so a sequence PSNR is one number, not a mean of per-frame dB."""
    m = mse_tonemapped(pred, ref)
    m = float(m) if xp(pred) is np else float(m.detach())
    return float("inf") if m == 0 else -10.0 * math.log10(m)


def trmae(pred_seq, ref_seq, eps: float = TRMAE_EPS) -> float:
    """ANF Eq. 16: temporal relative MAE of sequences shaped (T, H, W, 3), T >= 2.

    ``1/3 * E_xyt[ ||d_t O - d_t O*||_1 / (||d_t O*||_1 + eps) ]``: temporal derivatives are
    frame differences (T - 1 of them), ``||.||_1`` is the L1 norm over the 3 colour channels of
    one pixel, and E is the mean over pixels and t.  Lower is better; 0 for identical motion.
    """
    pred_seq = np.asarray(pred_seq, dtype=np.float64)
    ref_seq = np.asarray(ref_seq, dtype=np.float64)
    if pred_seq.shape != ref_seq.shape or pred_seq.ndim != 4 or pred_seq.shape[0] < 2:
        raise ValueError(f"trmae needs two (T>=2, H, W, 3) sequences, got {pred_seq.shape} and "
                         f"{ref_seq.shape}")
    dp = np.diff(pred_seq, axis=0)
    dr = np.diff(ref_seq, axis=0)
    num = np.abs(dp - dr).sum(axis=-1)
    den = np.abs(dr).sum(axis=-1) + eps
    return float(np.mean(num / den) / pred_seq.shape[-1])


#: SSIM constants (Wang et al. 2004): window, dynamic range L and K1, K2.
SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03
SSIM_L = 1.0


def _gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    x = np.arange(size, dtype=np.float64) - (size - 1) / 2.0
    g = np.exp(-x * x / (2.0 * sigma * sigma))
    return g / g.sum()


def _filter_valid(x: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Separable 2-D correlation of ``x`` (..., H, W, C) with ``g`` x ``g`` over H and W, keeping
    only positions where the window lies inside the image (H - k + 1, W - k + 1)."""
    k = len(g)
    h, w = x.shape[-3], x.shape[-2]
    rows = sum(g[i] * x[..., i:i + h - k + 1, :, :] for i in range(k))
    return sum(g[i] * rows[..., :, i:i + w - k + 1, :] for i in range(k))


def _as_images(pred, ref, what: str) -> tuple[np.ndarray, np.ndarray]:
    pred = np.asarray(pred)
    ref = np.asarray(ref)
    if pred.shape != ref.shape or pred.ndim not in (3, 4) or pred.shape[-1] != 3:
        raise ValueError(f"{what} needs two (H, W, 3) images or (T, H, W, 3) stacks of the same "
                         f"shape, got {pred.shape} and {ref.shape}")
    return pred, ref


def ssim(pred, ref) -> float:
    """SSIM (Wang et al. 2004) on ANF Eq. 15-tonemapped radiance, the images PSNR sees.

    numpy only.  ``pred``, ``ref``: (H, W, 3) linear radiance, or (T, H, W, 3) stacks, with
    H, W >= 11.  Both are tonemapped by :func:`runtime.transfer.reinhard_gamma` (values in
    [0, 1), so L = 1), then per colour channel the standard SSIM map is computed with an
    11 x 11 Gaussian window (sigma 1.5, normalised to sum 1), weighted (population) local means,
    variances and covariance, K1 = 0.01, K2 = 0.03:
    ``(2 mu_x mu_y + C1)(2 s_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(s_x^2 + s_y^2 + C2))`` with
    C1 = (K1 L)^2, C2 = (K2 L)^2.  The map is taken only at *valid* window positions (the window
    inside the image: (H - 10) x (W - 10) per channel, no padding) and the result is the mean
    over those positions, the 3 channels and the frames.  Range [-1, 1], 1 for identical images.
    """
    pred, ref = _as_images(pred, ref, "ssim")
    if min(pred.shape[-3:-1]) < SSIM_WINDOW:
        raise ValueError(f"ssim needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels, "
                         f"got {pred.shape[-2]}x{pred.shape[-3]}")
    x = reinhard_gamma(pred.astype(np.float64))
    y = reinhard_gamma(ref.astype(np.float64))
    g = _gaussian_window()
    mx, my = _filter_valid(x, g), _filter_valid(y, g)
    sxx = _filter_valid(x * x, g) - mx * mx
    syy = _filter_valid(y * y, g) - my * my
    sxy = _filter_valid(x * y, g) - mx * my
    c1, c2 = (SSIM_K1 * SSIM_L) ** 2, (SSIM_K2 * SSIM_L) ** 2
    smap = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return float(np.mean(smap))


#: Pixels per degree of visual angle FLIP assumes (its default: 0.7 m from a 0.7 m wide
#: 3840-pixel monitor).
FLIP_PPD = 67.0


def flip(pred, ref) -> float:
    """Mean NVIDIA FLIP error (Andersson et al. 2020) via the ``flip-evaluator`` package.

    numpy only.  ``pred``, ``ref``: (H, W, 3) linear radiance or (T, H, W, 3) stacks (mean over
    frames).  Range [0, 1], 0 for identical images; lower is better.

    This is **LDR-FLIP on the ANF Eq. 15-tonemapped images** (:func:`runtime.transfer.reinhard_gamma`,
    values in [0, 1), passed as display-encoded sRGB: FLIP linearises them with the sRGB curve,
    close to the inverse of the 1/2.4 power), at :data:`FLIP_PPD` pixels per degree.  Why not
    HDR-FLIP on linear radiance: it tonemaps with its own operator (ACES) at a number of
    exposures it derives from each reference's dynamic range, so its cost varies per image and
    it scores a different display than PSNR/SSIM do.  Measured here (2 cores, 256x256 tiles of
    the test set): LDR-FLIP 50-70 ms, HDR-FLIP 215-410 ms (4-8 exposures); on random 720p data
    0.57 s vs 1.3 s.  LDR-FLIP on the same tonemapped images keeps PSNR, SSIM and FLIP on one
    display and is 4-8x cheaper.  Non-finite input (which FLIP's C++ code must not see) counts
    as 0 for NaN and as saturated white for +inf.
    """
    pred, ref = _as_images(pred, ref, "flip")
    try:
        import flip_evaluator
    except ImportError as e:
        raise ImportError("flip() needs the 'flip-evaluator' package: pip install flip-evaluator "
                          "(or the project's [bench] extra)") from e
    big = float(np.finfo(np.float32).max)  # tonemaps to 1
    x = reinhard_gamma(np.nan_to_num(pred.astype(np.float32), nan=0.0, posinf=big))
    y = reinhard_gamma(np.nan_to_num(ref.astype(np.float32), nan=0.0, posinf=big))
    if x.ndim == 3:
        x, y = x[None], y[None]
    errs = []
    for a, b in zip(x, y):
        _, mean, _ = flip_evaluator.evaluate(np.ascontiguousarray(b, dtype=np.float32),
                                             np.ascontiguousarray(a, dtype=np.float32), "LDR",
                                             inputsRGB=True, applyMagma=False,
                                             computeMeanError=True, parameters={"ppd": FLIP_PPD})
        errs.append(float(mean))
    return float(np.mean(errs))


def warped_temporal_error(pred_seq, ref_seq, frames) -> float | None:
    """Motion-compensated temporal error of a sequence, relative to the reference's: the
    flicker (or lag) a viewer sees along the motion, where TRMAE compares frame differences
    pixel by pixel. Σ_t prediction error / Σ_t reference error of
    :func:`warped_error_sums`: 1 means as steady as the reference, more means flicker, less
    means smoothed in time beyond the reference (lag, ghosting). None when no frame has a
    warpable history (one frame, no motion vectors, nothing valid)."""
    p, r = warped_error_sums(pred_seq, ref_seq, frames)
    return None if r == 0 else p / r


def warped_error_sums(pred_seq, ref_seq, frames) -> tuple[float, float]:
    """(Σ prediction error, Σ reference error) of :func:`warped_temporal_error`.

    For each frame t >= 1, frame t-1 is warped onto frame t along the true motion vectors with
    the driver's reprojection and consistency test (:func:`runtime.temporal.reproject`, guides
    from ``frames``), and the absolute differences of ANF Eq. 15-tonemapped values are summed
    over the pixels with a consistent history there (and, when the frame has the renderer's
    ``valid`` layer, visible in t-1), for the prediction and for the reference alike.

    pred_seq, ref_seq: (T, H, W, 3) linear HDR; frames: the T :class:`runtime.frames.Frame`
    (motion, depth, and position / normal when present)."""
    from mcdenoise.runtime.temporal import reproject

    def nchw(a):
        return np.ascontiguousarray(np.asarray(a, np.float32).transpose(2, 0, 1)[None])

    def guides(fr):
        return {k: nchw(getattr(fr, k)) for k in ("depth", "position", "normal") if getattr(fr, k) is not None}

    sums = [0.0, 0.0]
    for t in range(1, len(frames)):
        cur, prev = frames[t], frames[t - 1]
        if cur.motion is None or cur.depth is None or prev.depth is None or cur.size != prev.size:
            continue
        motion = np.nan_to_num(nchw(cur.motion))
        warped, hist = reproject([nchw(pred_seq[t - 1]), nchw(ref_seq[t - 1])], motion, guides(cur), guides(prev))
        ok = hist[0, 0] > 0
        if cur.valid is not None:
            ok &= np.asarray(cur.valid)[..., 0] > 0
        for k, (seq, w) in enumerate(zip((pred_seq, ref_seq), warped)):
            e = np.abs(reinhard_gamma(np.asarray(seq[t], np.float32)) - reinhard_gamma(w[0].transpose(1, 2, 0)))
            sums[k] += float(e[ok].sum())
    return sums[0], sums[1]
