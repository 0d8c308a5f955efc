"""SVGF-style classical temporal filter: the non-neural baseline (numpy only, no torch).

After Schied et al. 2017, "Spatiotemporal Variance-Guided Filtering: Real-Time Reconstruction
for Path-Traced Global Illumination" (HPG 2017).  Per frame:

1. **Sanitise** the frame as the runtime does (:func:`runtime.inputs.sanitize_array`: colour
   non-finite/negative -> 0, huge clamped; guides non-finite -> 0), so NaN/Inf never reach the
   state.
2. **Demodulate** by albedo: ``illum = color / (albedo + ALBEDO_EPS)`` (the models' convention).
3. **Temporal accumulation**: the previous integrated illumination, luminance moments and
   history length are warped with :func:`runtime.temporal.reproject` (motion vectors; world
   position, world normal and depth consistency test, the driver's guide buffers); where no
   history survives the length restarts at 1.  Colour and moments are blended with
   ``alpha = max(0.2, 1 / n)`` (n = history length: a plain mean while the history is short).
   Variance = ``max(0, E[l^2] - E[l]^2)`` of the luminance ``l``.  While ``n < 4`` the variance
   is instead estimated spatially from the current frame's luminance moments over a 3 x 3 box
   (SVGF uses a 7 x 7 edge-aware bilateral filter; the box is our simplification) and boosted by
   ``4 / n`` as SVGF does.
4. **À-trous wavelet filter**: :data:`ITERATIONS` = 5 passes of the 5 x 5 B3-spline kernel
   (1/16, 1/4, 3/8, 1/4, 1/16) with step 2^i.  Weight of tap q for pixel p: the kernel weight
   times edge-stopping functions on depth
   ``exp(-|z_p - z_q| / (SIGMA_Z |grad z_p . (p - q)| + DEPTH_EPS_REL z_p))`` (the gradient is the
   smaller one-sided difference per axis, so it stays small at a silhouette), normal
   ``(n_p . n_q)^128``, evaluated as ``exp(128 (n_p . n_q - 1))`` (equal to first order at
   n_p . n_q = 1, e.g. 0.278 vs 0.276 at 0.99 and 0.0017 vs 0.0014 at 0.95; ~0 for misses,
   whose normal is 0) so that it shares one ``exp`` with the depth and luminance terms, and
   illumination luminance ``exp(-|l_p - l_q| / (SIGMA_L sqrt(g3x3(var_p)) + 1e-10))`` with
   SIGMA_L = 4 and g3x3 the 3 x 3 Gaussian prefilter of the variance.  Variance is filtered along with weights squared.  The
   first pass's output becomes the colour history (SVGF's feedback); the moments history stays
   unfiltered.  Image borders are padded by edge replication.
5. **Re-modulate** by ``albedo + ALBEDO_EPS``.

A camera cut (``meta["cut"]``) or a resolution change resets the state; so does :meth:`reset`.
Frames without albedo are filtered without demodulation, without normals without the normal
term, without depth as if at unit depth (no depth term), as the runtime driver does for guides.
"""
from __future__ import annotations

import numpy as np

from mcdenoise.runtime.denoiser import GUIDE_LAYERS, _as_frame
from mcdenoise.runtime.frames import FrameError
from mcdenoise.runtime.inputs import ALBEDO_EPS, SanitizeReport, sanitize_array
from mcdenoise.runtime.temporal import reproject
from mcdenoise.runtime.workers import default_threads
from mcdenoise.runtime.transfer import LUMA as TRANSFER_LUMA

#: Exponential moving average weights of colour and moments (SVGF: 0.2 each).
ALPHA_COLOR = 0.2
ALPHA_MOMENTS = 0.2
#: History shorter than this uses the spatial variance estimate.
MIN_HISTORY_FOR_TEMPORAL_VARIANCE = 4
#: À-trous iterations (step 1, 2, 4, 8, 16) and the B3-spline taps.
ITERATIONS = 5
B3 = np.array([1 / 16, 1 / 4, 3 / 8, 1 / 4, 1 / 16], np.float32)
#: Edge-stopping parameters (SVGF: sigma_z = 1, sigma_n = 128, sigma_l = 4).
SIGMA_Z = 1.0
SIGMA_N = 128
SIGMA_L = 4.0
#: Relative depth floor in the depth term's denominator (fronto-parallel planes have no gradient).
DEPTH_EPS_REL = 1e-3
#: Luminance weights (Rec. 709).
LUMA = np.array(TRANSFER_LUMA, np.float32)
#: Output rows processed at a time by the à-trous filter (temporaries stay in cache).
BAND_ROWS = 16


def _luminance(c: np.ndarray) -> np.ndarray:
    """(3, H, W) -> (H, W)."""
    return LUMA[0] * c[0] + LUMA[1] * c[1] + LUMA[2] * c[2]


def _box3(x: np.ndarray) -> np.ndarray:
    """3 x 3 box mean over the last two axes, edge-padded."""
    p = np.pad(x, [(0, 0)] * (x.ndim - 2) + [(1, 1), (1, 1)], mode="edge")
    h, w = x.shape[-2:]
    rows = p[..., 0:h, :] + p[..., 1:h + 1, :] + p[..., 2:h + 2, :]
    return (rows[..., 0:w] + rows[..., 1:w + 1] + rows[..., 2:w + 2]) * np.float32(1 / 9)


def _gauss3(x: np.ndarray) -> np.ndarray:
    """3 x 3 Gaussian (1 2 1) x (1 2 1) / 16 over (H, W), edge-padded (SVGF's variance prefilter)."""
    p = np.pad(x, 1, mode="edge")
    h, w = x.shape
    rows = p[0:h] + 2 * p[1:h + 1] + p[2:h + 2]
    return (rows[:, 0:w] + 2 * rows[:, 1:w + 1] + rows[:, 2:w + 2]) * np.float32(1 / 16)


def _depth_gradient(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel |dz/dx|, |dz/dy| as the smaller one-sided difference (small at silhouettes)."""
    p = np.pad(z, 1, mode="edge")
    c = p[1:-1, 1:-1]
    gx = np.minimum(np.abs(p[1:-1, 2:] - c), np.abs(c - p[1:-1, :-2]))
    gy = np.minimum(np.abs(p[2:, 1:-1] - c), np.abs(c - p[:-2, 1:-1]))
    return gx, gy


def atrous_step(illum: np.ndarray, var: np.ndarray, depth: np.ndarray, grad: tuple,
                normal: np.ndarray | None, step: int) -> tuple[np.ndarray, np.ndarray]:
    """One edge-aware à-trous pass.

    Args:
      illum: (3, H, W) float32 demodulated illumination; var: (H, W) its luminance variance;
      depth: (H, W) (0 on a miss); grad: (|dz/dx|, |dz/dy|) each (H, W); normal: (3, H, W)
      world-space unit normals or None; step: tap spacing in pixels.

    Returns:
      (filtered illumination (3, H, W), filtered variance (H, W)), float32.
    """
    h, w = depth.shape
    r = 2 * step
    lum = _luminance(illum)
    inv_l = 1.0 / (SIGMA_L * np.sqrt(np.maximum(_gauss3(var), 0.0)) + 1e-10)
    pad2 = ((r, r), (r, r))
    p_illum = np.pad(illum, ((0, 0),) + pad2, mode="edge")
    p_var = np.pad(var, pad2, mode="edge")
    p_lum = np.pad(lum, pad2, mode="edge")
    p_z = np.pad(depth, pad2, mode="edge")
    p_n = None if normal is None else np.pad(normal, ((0, 0),) + pad2, mode="edge")
    gx, gy = grad
    out_c = np.empty_like(illum)
    out_v = np.empty_like(var)

    def band(y0: int) -> None:
        y1 = min(h, y0 + BAND_ROWS)
        zp = depth[y0:y1]
        lp = lum[y0:y1]
        il = inv_l[y0:y1]
        floor = DEPTH_EPS_REL * zp + 1e-12
        gxb = SIGMA_Z * gx[y0:y1]
        gyb = SIGMA_Z * gy[y0:y1]
        n_s = None if normal is None else normal[:, y0:y1] * np.float32(SIGMA_N)
        # The centre tap's edge-stopping terms are 1 by definition (also for a miss, whose
        # normal is 0): its weight is the kernel's alone.
        k0 = B3[2] * B3[2]
        acc_c = illum[:, y0:y1] * k0
        acc_v = var[y0:y1] * (k0 * k0)
        wsum = np.full(zp.shape, k0, np.float32)
        inv_z = {}
        for j in range(5):
            for i in range(5):
                if i == 2 and j == 2:
                    continue
                dx, dy = (i - 2) * step, (j - 2) * step
                key = (abs(dx), abs(dy))
                if key not in inv_z:
                    inv_z[key] = 1.0 / (gxb * abs(dx) + gyb * abs(dy) + floor)
                ys = slice(y0 + r + dy, y1 + r + dy)
                xs = slice(r + dx, r + dx + w)
                # weight = kernel * exp(-(depth term + luminance term) + SIGMA_N (n_p . n_q - 1)),
                # as one exp: e = depth + luminance - SIGMA_N n_p . n_q, c0 = log kernel - SIGMA_N.
                e = np.abs(p_z[ys, xs] - zp)
                e *= inv_z[key]
                t = np.abs(p_lum[ys, xs] - lp)
                t *= il
                e += t
                c0 = np.float32(np.log(B3[i] * B3[j]))
                if n_s is not None:
                    nq = p_n[:, ys, xs]
                    t = np.multiply(nq[0], n_s[0], out=t)
                    t += nq[1] * n_s[1]
                    t += nq[2] * n_s[2]
                    e -= t
                    c0 -= np.float32(SIGMA_N)
                wgt = np.exp(np.subtract(c0, e, out=e), out=e)
                wsum += wgt
                acc_c += wgt * p_illum[:, ys, xs]
                wgt *= wgt
                acc_v += wgt * p_var[ys, xs]
        out_c[:, y0:y1] = acc_c / wsum
        out_v[y0:y1] = acc_v / (wsum * wsum)

    for y0 in range(0, h, BAND_ROWS):
        band(y0)
    return out_c, out_v


class SVGF:
    """The SVGF-style baseline behind the method interface (:mod:`training.methods`).

    ``svgf(frame) -> (H, W, 3) float32`` linear HDR radiance; ``reset()`` forgets the history.
    The frame is a :class:`runtime.frames.Frame` or a dict of (H, W, C) layers; ``color`` is
    required, ``albedo``, ``normal`` (world space), ``depth``, ``position`` and ``motion`` are
    used when present.  Not thread-safe.
    """

    name = "svgf"

    def __init__(self, iterations: int = ITERATIONS, alpha_color: float = ALPHA_COLOR,
                 alpha_moments: float = ALPHA_MOMENTS):
        self.iterations = int(iterations)
        self.alpha_color = float(alpha_color)
        self.alpha_moments = float(alpha_moments)
        self.report = SanitizeReport()
        self.reset()

    def reset(self) -> None:
        """Forget the temporal state (integrated colour, moments, history length, guides)."""
        self._illum = None  # (1, 3, H, W) first à-trous pass of the last frame
        self._moments = None  # (1, 2, H, W)
        self._length = None  # (1, 1, H, W)
        self._guides = None
        self._size = None

    def _guides_of(self, fr) -> dict[str, np.ndarray]:
        g = {}
        for name in GUIDE_LAYERS:
            arr = getattr(fr, name)
            if arr is not None:
                g[name] = np.ascontiguousarray(
                    sanitize_array(arr, False, name, self.report).transpose(2, 0, 1)[None])
        if "depth" not in g:
            g["depth"] = np.ones((1, 1, *fr.size), np.float32)
        return g

    def __call__(self, frame) -> np.ndarray:
        fr = _as_frame(frame)
        fr.validate()
        if fr.color.ndim != 3 or fr.color.shape[2] != 3:
            raise FrameError(f"{fr.path or 'frame'}: color must be (H, W, 3), got {fr.color.shape}")
        h, w = fr.size
        if self._size != (h, w) or (fr.meta or {}).get("cut"):
            self.reset()
        self._size = (h, w)

        color = sanitize_array(fr.color, True, "color", self.report).transpose(2, 0, 1)
        if fr.albedo is not None:
            albedo = sanitize_array(fr.albedo, False, "albedo", self.report)
            modulation = np.maximum(albedo, 0.0).transpose(2, 0, 1) + np.float32(ALBEDO_EPS)
        else:
            modulation = np.ones((3, h, w), np.float32)
        illum = (color / modulation).astype(np.float32)
        guides = self._guides_of(fr)
        depth = guides["depth"][0, 0]
        normal = guides["normal"][0] if "normal" in guides else None

        lum = _luminance(illum)
        mom = np.stack([lum, lum * lum])
        # --- temporal accumulation
        if self._illum is not None:
            if fr.motion is not None:
                motion = sanitize_array(fr.motion, False, "motion", self.report).transpose(2, 0, 1)[None]
            else:
                motion = np.zeros((1, 2, h, w), np.float32)
            (p_illum, p_mom, p_len), hist = reproject([self._illum, self._moments, self._length],
                                                      motion, guides, self._guides, threads=default_threads())
            length = p_len[0, 0] * hist[0, 0] + 1.0
            p_illum, p_mom = p_illum[0], p_mom[0]
        else:
            length = np.ones((h, w), np.float32)
            p_illum, p_mom = np.zeros_like(illum), np.zeros_like(mom)
        a_c = np.maximum(self.alpha_color, 1.0 / length).astype(np.float32)
        a_m = np.maximum(self.alpha_moments, 1.0 / length).astype(np.float32)
        acc_illum = p_illum + a_c * (illum - p_illum)
        acc_mom = p_mom + a_m * (mom - p_mom)
        var = np.maximum(acc_mom[1] - acc_mom[0] ** 2, 0.0)
        short = length < MIN_HISTORY_FOR_TEMPORAL_VARIANCE
        if short.any():
            m = _box3(mom)
            var_sp = np.maximum(m[1] - m[0] ** 2, 0.0) * (MIN_HISTORY_FOR_TEMPORAL_VARIANCE / length)
            var = np.where(short, var_sp, var)
        var = var.astype(np.float32)

        # --- à-trous
        grad = _depth_gradient(depth)
        c, v = acc_illum.astype(np.float32), var
        feedback = c
        for it in range(self.iterations):
            c, v = atrous_step(c, v, depth, grad, normal, 1 << it)
            if it == 0:
                feedback = c
        self._illum = np.ascontiguousarray(feedback[None], dtype=np.float32)
        self._moments = np.ascontiguousarray(acc_mom[None], dtype=np.float32)
        self._length = length[None, None].astype(np.float32)
        self._guides = guides
        out = (c * modulation).transpose(1, 2, 0)
        return np.ascontiguousarray(np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0), dtype=np.float32)
