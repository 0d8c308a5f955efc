"""Image-quality metrics: the one definition used by training, bench and tests.

Every function takes numpy arrays or torch tensors (same namespace for both arguments) of
linear HDR radiance with the channel axis last for numpy ``(..., H, W, 3)`` or anywhere for
torch, and reduces over all elements.  torch input keeps gradients (losses use these too).
"""
from __future__ import annotations

import math

import numpy as np

from runtime.transfer import reinhard_gamma, xp

#: epsilon of SMAPE (WSKPN Eq. 6, Vogels et al. 2018) and relMSE / TRMAE (ANF Eq. 16).
SMAPE_EPS = 0.01
RELMSE_EPS = 0.01
TRMAE_EPS = 0.01


def _mean(x):
    return x.mean()


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

    Temporal derivatives are frame differences; the mean runs over pixels, channels and t.
    """
    pred_seq = np.asarray(pred_seq, dtype=np.float64)
    ref_seq = np.asarray(ref_seq, dtype=np.float64)
    if pred_seq.shape != ref_seq.shape or pred_seq.ndim != 4 or pred_seq.shape[0] < 2:
        raise ValueError(f"trmae needs two (T>=2, H, W, 3) sequences, got {pred_seq.shape} and "
                         f"{ref_seq.shape}")
    dp = np.diff(pred_seq, axis=0)
    dr = np.diff(ref_seq, axis=0)
    return float(np.mean(np.abs(dp - dr) / (np.abs(dr) + eps)))
