"""Transfer functions (tone curves) shared by training, export, metrics and the runtime.

This is the one definition of every curve the package applies to radiance.  Each function
works on numpy arrays and on torch tensors alike (the array namespace is picked from the
argument, so this module never imports torch itself) and keeps gradients for torch input.

Radiance is linear HDR, in the renderer's units (Mitsuba: W·sr⁻¹·m⁻² per RGB channel),
non-negative for valid input.  Curves clamp negative values to 0 before applying themselves.
"""
from __future__ import annotations

import sys
from typing import Any, Callable

import numpy as np

#: Gamma of the "gamma" curve (WSKPN §5.1, BMFR data: gamma correction to LDR).
GAMMA = 2.2
#: Exponent of the Reinhard + gamma operator used for PSNR (ANF Eq. 15).
REINHARD_GAMMA = 2.4


#: Rec. 709 luminance weights of linear RGB: the one definition (models, SVGF, exposure).
LUMA = (0.2126, 0.7152, 0.0722)


def luminance(color, axis: int = 1):
    """Rec. 709 luminance of linear RGB along ``axis`` (default 1: NCHW), keeping that axis
    with size 1: (N, 3, H, W) -> (N, 1, H, W).  numpy or torch."""
    idx = [slice(None)] * color.ndim

    def ch(c):
        idx[axis] = slice(c, c + 1)
        return color[tuple(idx)]

    return LUMA[0] * ch(0) + LUMA[1] * ch(1) + LUMA[2] * ch(2)


def xp(x: Any):
    """Array namespace of ``x``: the torch module for tensors, else numpy."""
    if type(x).__module__.startswith("torch"):
        return sys.modules["torch"]
    return np


def _clamp0(x):
    if xp(x) is np:
        return np.maximum(x, 0.0)
    return x.clamp(min=0.0)


def _clamp01(x):
    if xp(x) is np:
        return np.clip(x, 0.0, 1.0)
    return x.clamp(0.0, 1.0)


#: Floor applied before fractional powers: x**p has an infinite slope at 0, so torch would
#: produce inf/NaN gradients there; clamping to this floor gives a zero gradient instead
#: and changes values by < 1e-12.
POW_FLOOR = 1e-30


def _pow_floor(x, p, hi=None):
    """``max(x, POW_FLOOR) ** p`` (and at most ``hi ** p``), computed as exp(p·log(·)):
    onnxruntime's Pow runs a scalar pow per value (3 channels at 1280x720: 7.7 ms) where Log,
    Mul and Exp are vectorised (4.5 ms together).  Equal to the power up to float rounding."""
    if xp(x) is np:
        return np.exp(np.log(np.clip(x, POW_FLOOR, hi)) * p)
    return (x.clamp(min=POW_FLOOR, max=hi).log() * p).exp()


def gamma(x):
    """LDR gamma curve: ``clip(x, 0, 1) ** (1/2.2)``. Input linear radiance, output [0, 1].

    Values above 1 saturate (the paper's LDR input).
    """
    return _pow_floor(x, 1.0 / GAMMA, hi=1.0)


def gamma_inv(y):
    """Inverse of :func:`gamma` on [0, 1]."""
    return _clamp01(y) ** GAMMA


def log1p(x):
    """``log(1 + max(x, 0))`` (ANF/NDLE sample input, KPCN). Output [0, inf)."""
    return xp(x).log1p(_clamp0(x))


def log1p_inv(y):
    """Inverse of :func:`log1p`."""
    return xp(y).expm1(_clamp0(y))


def reinhard_gamma(x):
    """ANF Eq. 15: ``(x / (1 + x)) ** (1/2.4)`` for x >= 0. Output [0, 1)."""
    x = _clamp0(x)
    return _pow_floor(x / (1.0 + x), 1.0 / REINHARD_GAMMA)


def identity(x):
    """Linear radiance, unchanged."""
    return x


#: Name -> (forward, inverse).  Specs and ONNX metadata refer to curves by these names.
TRANSFERS: dict[str, tuple[Callable, Callable | None]] = {
    "linear": (identity, identity),
    "gamma": (gamma, gamma_inv),
    "log1p": (log1p, log1p_inv),
    "reinhard_gamma": (reinhard_gamma, None),
}


def get(name: str) -> Callable:
    """Forward curve by name; raises ``KeyError`` listing the known names."""
    try:
        return TRANSFERS[name][0]
    except KeyError:
        raise KeyError(f"unknown transfer function {name!r}; known: {sorted(TRANSFERS)}") from None
