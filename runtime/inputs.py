"""Frame -> model input tensors: the one definition shared by the dataset and the runtime driver.

Model inputs are NCHW float32.  Pixel layers map to inputs by name (``color``, ``albedo``,
``normal``, ``depth``, ...).  Two conversions happen here and nowhere else:

* **Sanitising** radiance: non-finite values become 0, negatives become 0, values above
  :data:`MAX_RADIANCE` are clamped; the counts are reported so callers can say so.
* **Screen-space normals**: the renderer stores world-space normals; models see them in the
  camera's screen-aligned frame (x right, y down, z forward into the scene), so that image
  flips and 90° rotations act on normals exactly as on motion vectors (negate/swap x, y).
  Frames without a camera in their metadata (plain OIDN-style input) keep their normals.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mcdenoise.runtime.frames import Frame
from mcdenoise.runtime.workers import run_all

#: Radiance above this is clamped when sanitising (units of the renderer; our scenes' emitters
#: are <= ~100, so only broken samples get here).  Chosen below float16's max (65504) so
#: half-precision graphs never see inf.
MAX_RADIANCE = 6.0e4
#: Layers holding radiance (sanitised); geometric layers get non-finite -> 0 only.
RADIANCE_LAYERS = ("color", "reference")


@dataclass
class SanitizeReport:
    """What sanitising changed, per layer: counts of pixels' values replaced."""

    nonfinite: dict = field(default_factory=dict)
    negative: dict = field(default_factory=dict)
    clamped: dict = field(default_factory=dict)

    @property
    def total(self) -> int:
        return sum(self.nonfinite.values()) + sum(self.negative.values()) + sum(self.clamped.values())

    def summary(self) -> str:
        parts = []
        for what, d in (("non-finite", self.nonfinite), ("negative", self.negative),
                        ("above max", self.clamped)):
            for layer, n in d.items():
                if n:
                    parts.append(f"{n} {what} values in {layer}")
        return ", ".join(parts) if parts else "clean"


#: Albedo demodulation epsilon, for every method that filters irradiance (WSKPN, NBG, SVGF):
#: irradiance = radiance / (albedo + ALBEDO_EPS), multiplied back by the same factor, so an
#: identity filter returns its input exactly.  0 albedo (misses, delta BSDFs) makes
#: irradiance 100x radiance there.
ALBEDO_EPS = 1e-2
#: Auto-exposure (as Open Image Denoise does for HDR input): every sequence's colour is scaled
#: so that the geometric mean of its 16x16-block mean luminances is this key, and the output
#: scaled back.  The models then see the same exposure whatever the renderer's units (a model
#: trained on our renders lost 2-4 dB at x1/1000 and x1000 exposure without it, measured by
#: ``mcdenoise stress``).  0.18 sits inside our training data's spread (0.02-0.94, median 0.21).
AUTOEXPOSURE_KEY = 0.18
#: Block size (pixels) of the auto-exposure's luminance means: averaging blocks first keeps
#: 1-spp noise (many black samples) from dragging the geometric mean down.
AUTOEXPOSURE_BLOCK = 16
#: Blocks darker than this are left out of the geometric mean (black background, misses).
AUTOEXPOSURE_MIN = 1e-8


def exposure_scale(color):
    """Auto-exposure factor per image: (N, 3, H, W) linear HDR radiance (sanitised, numpy or
    torch) -> (N, 1, 1, 1) positive factors s with ``s * color`` at :data:`AUTOEXPOSURE_KEY`.

    Images smaller than a block use their whole-image mean; an image with no block brighter
    than :data:`AUTOEXPOSURE_MIN` gets 1.  Not differentiated (a per-image constant).
    """
    from mcdenoise.runtime.transfer import luminance, xp

    lib = xp(color)
    lum = luminance(color, 1)[:, 0]                                   # (N, H, W)
    n, h, w = lum.shape
    b = AUTOEXPOSURE_BLOCK if min(h, w) >= AUTOEXPOSURE_BLOCK else min(h, w)
    hb, wb = h // b, w // b
    blocks = lum[:, :hb * b, :wb * b].reshape(n, hb, b, wb, b).mean(axis=(2, 4)) if lib is np else \
        lum[:, :hb * b, :wb * b].reshape(n, hb, b, wb, b).mean(dim=(2, 4)).detach()
    blocks = blocks.reshape(n, -1)
    bright = blocks > AUTOEXPOSURE_MIN
    logs = lib.log(lib.maximum(blocks, blocks * 0 + AUTOEXPOSURE_MIN)) * bright
    count = bright.sum(1)
    if lib is np:
        mean_log = logs.sum(1) / np.maximum(count, 1)
        scale = np.where(count > 0, AUTOEXPOSURE_KEY / np.exp(mean_log), 1.0).astype(color.dtype)
    else:
        mean_log = logs.sum(1) / count.clamp(min=1)
        scale = lib.where(count > 0, AUTOEXPOSURE_KEY / lib.exp(mean_log), lib.ones_like(mean_log)).to(color.dtype)
    return scale.reshape(n, 1, 1, 1)


#: What replaces a non-finite value, per layer (0 for layers not listed).  Albedo gets 1, the
#: neutral value of albedo demodulation: with 0 a pixel whose albedo is broken would be
#: re-modulated to black by every demodulating method (WSKPN, NBG, SVGF); with 1 it keeps its
#: filtered radiance.
NONFINITE_FILL = {"albedo": 1.0}


def _clean(lo, hi, radiance: bool, top=MAX_RADIANCE) -> bool:
    """Whether a layer with these extrema needs no sanitising (radiance: none above ``top``)."""
    return bool(np.isfinite(lo) and np.isfinite(hi) and (not radiance or (lo >= 0 and hi <= top)))


def _sanitize_inplace(out: np.ndarray, radiance: bool, name: str, report: SanitizeReport,
                      lo=None, hi=None) -> np.ndarray:
    """:func:`sanitize_array` on a float32 array the caller owns (modified in place); ``lo``,
    ``hi``: its min and max when the caller has them already."""
    # A NaN or ±inf makes min or max non-finite: two reductions decide that a frame is clean,
    # the common case, without the mask passes the repair below needs.
    if lo is None or hi is None:
        lo, hi = out.min(initial=0.0), out.max(initial=0.0)
    if _clean(lo, hi, radiance):
        return out
    bad = ~np.isfinite(out)
    if bad.any():
        report.nonfinite[name] = report.nonfinite.get(name, 0) + int(bad.sum())
        out[bad] = NONFINITE_FILL.get(name, 0.0)
    if radiance:
        neg = out < 0
        if neg.any():
            report.negative[name] = report.negative.get(name, 0) + int(neg.sum())
            out[neg] = 0.0
        big = out > MAX_RADIANCE
        if big.any():
            report.clamped[name] = report.clamped.get(name, 0) + int(big.sum())
            out[big] = MAX_RADIANCE
    return out


def sanitize_array(arr: np.ndarray, radiance: bool, name: str, report: SanitizeReport) -> np.ndarray:
    """Copy of ``arr`` (float32) with non-finite values -> :data:`NONFINITE_FILL` (default 0)
    and, for radiance, negatives -> 0 and values above :data:`MAX_RADIANCE` clamped; the counts
    go to ``report``."""
    return _sanitize_inplace(np.array(arr, dtype=np.float32, copy=True), radiance, name, report)


def camera_axes(meta: dict) -> np.ndarray | None:
    """3x3 matrix whose rows are the camera's screen right, screen down and forward axes in
    world space, from ``meta["camera"]["to_world"]`` (Mitsuba convention: local +x is screen
    left, +y up, +z forward), or None when the frame carries no camera."""
    cam = meta.get("camera") if isinstance(meta, dict) else None
    if not cam or "to_world" not in cam:
        return None
    m = np.asarray(cam["to_world"], dtype=np.float64)[:3, :3]
    axes = np.stack([-m[:, 0], -m[:, 1], m[:, 2]])
    return (axes / np.linalg.norm(axes, axis=1, keepdims=True)).astype(np.float32)


def screen_normals(normal: np.ndarray, meta: dict) -> np.ndarray:
    """World-space normals (..., 3) -> screen-aligned camera space (x right, y down, z fwd)."""
    axes = camera_axes(meta)
    if axes is None:
        return normal
    return (normal @ axes.T).astype(np.float32)


def screen_normal_planes(normal: np.ndarray, meta: dict) -> np.ndarray:
    """:func:`screen_normals` for channel-first normals (N, 3, H, W) -> new (N, 3, H, W) array
    (the input itself when the frame has no camera).  Plane arithmetic: 2x faster than a
    (H*W, 3) @ (3, 3) product on the driver's CPU."""
    axes = camera_axes(meta)
    if axes is None:
        return normal
    out = np.empty_like(normal)
    for i in range(3):
        np.multiply(normal[:, 0], axes[i, 0], out=out[:, i])
        out[:, i] += normal[:, 1] * axes[i, 1]
        out[:, i] += normal[:, 2] * axes[i, 2]
    return out


#: Rows per block when converting (H, W, C) layers to (C, H, W): a block's source stays in the
#: cache while its channels are scattered and its extrema taken (720p: 3.2 ms a layer against
#: 3.8 for 16-row blocks and 5+ for one whole-frame strided copy; small frames want few blocks).
_TRANSPOSE_ROWS = 64


def to_planes(arr: np.ndarray, out: np.ndarray | None = None, extrema: list | None = None,
              scale=None) -> np.ndarray:
    """(H, W, C) image layer -> contiguous float32 (1, C, H, W) array: ``out`` when given (of
    that shape and dtype), else a new one, times ``scale`` (a float32 scalar) when given.  ``extrema``: a list that receives
    [min, max] of the values written (NaN when there is a NaN), taken block by block while the
    block is in cache."""
    h, w, c = arr.shape
    if out is None or out.shape != (1, c, h, w) or out.dtype != np.float32:
        out = np.empty((1, c, h, w), np.float32)
    los, his = [], []
    for y in range(0, h, _TRANSPOSE_ROWS):
        block = out[0, :, y:y + _TRANSPOSE_ROWS]
        if scale is None:
            block[...] = arr[y:y + _TRANSPOSE_ROWS].transpose(2, 0, 1)
        else:
            np.multiply(arr[y:y + _TRANSPOSE_ROWS].transpose(2, 0, 1), scale, out=block)
        if extrema is not None:
            los.append(block.min())
            his.append(block.max())
    if extrema is not None:
        extrema[:] = [min(los, default=0.0, key=_nan_first), max(his, default=0.0, key=_nan_last)]
    return out


def _nan_first(v):
    return (not np.isnan(v), v)


def _nan_last(v):
    return (np.isnan(v), v)


#: :func:`from_planes` splits its rows between threads from this many values on.
SPLIT_MIN_VALUES = 1 << 20


def from_planes(chw: np.ndarray, scale=None, threads: int = 1, extrema: list | None = None) -> np.ndarray:
    """(C, H, W) -> new contiguous (H, W, C) array of the same dtype (the inverse of
    :func:`to_planes` for one image), times ``scale`` when given (a scalar of that dtype).
    ``threads`` > 1 splits the rows between worker threads; ``extrema``: a list that receives
    [min, max] of ``chw`` (NaN when there is a NaN), taken while its rows are in cache."""
    c, h, w = chw.shape
    out = np.empty((h, w, c), chw.dtype)

    def rows(y0: int, y1: int):
        flat = out[y0:y1].reshape(-1, c)
        # One strided write per channel: 2.0 ms at 720p, where row blocks (as in to_planes)
        # take 4-5.
        for i in range(c):
            if scale is None:
                flat[:, i] = chw[i, y0:y1].reshape(-1)
            else:
                np.multiply(chw[i, y0:y1].reshape(-1), scale, out=flat[:, i])
        return (chw[:, y0:y1].min(), chw[:, y0:y1].max()) if extrema is not None and y1 > y0 else None

    # Split only frames big enough to pay for the hand-off (256x256: 0.4 ms on one thread,
    # 0.9 on two; 1280x720: 7.3 -> 3.9 ms in the driver).
    n = max(1, min(threads, h)) if chw.size >= SPLIT_MIN_VALUES else 1
    parts = [r for r in run_all(rows, [(h * k // n, h * (k + 1) // n) for k in range(n)], threads) if r]
    if extrema is not None:
        extrema[:] = [min((p[0] for p in parts), default=0.0, key=_nan_first),
                      max((p[1] for p in parts), default=0.0, key=_nan_last)]
    return out


def frame_planes(frame: Frame, names, report: SanitizeReport | None = None,
                 buffers: dict | None = None, threads: int = 1,
                 scale: dict | None = None) -> dict[str, np.ndarray]:
    """Layers ``names`` of ``frame`` as a dict name -> sanitised (1, C, H, W) float32 arrays,
    in the frame's own spaces (normals in world space).  ``buffers`` (name -> array, updated
    here) lets a caller reuse last time's arrays, which at 720p saves the page faults of fresh
    11 MB blocks (~2 ms a layer).  ``threads`` > 1 converts layers on worker threads
    (:mod:`runtime.workers`); sanitising and its report stay on the calling thread.  ``scale``: name -> positive
    float32 factor a layer is multiplied by on the way (the driver's auto-exposure: one pass
    fewer over the colour); the result is that of sanitising first and scaling after.
    Raises FrameError naming the frame and the missing layer."""
    report = SanitizeReport() if report is None else report
    layers = [(name, frame.layer(name)) for name in names]   # FrameError before any work

    def convert(name, arr):
        ext: list = []
        return to_planes(arr, None if buffers is None else buffers.get(name), ext, scales.get(name)), ext

    scales = scale or {}

    out = {}
    for (name, src), (arr, ext) in zip(layers, run_all(convert, layers, threads)):
        if buffers is not None:
            buffers[name] = arr
        radiance, s = name in RADIANCE_LAYERS, scales.get(name)
        # Scaled values: clean only clearly below the scaled bound (rounding of x·s must not
        # let a value just above MAX_RADIANCE through unclamped).
        if s is not None and not _clean(*ext, radiance, MAX_RADIANCE * float(s) * (1 - 1e-6)):
            # Something to sanitise (rare): in the layer's own units, as without a scale.
            ext = []
            to_planes(src, arr, ext)
            arr = _sanitize_inplace(arr, radiance, name, report, *ext)
            out[name] = np.multiply(arr, s, out=arr)
            continue
        out[name] = _sanitize_inplace(arr, radiance, name, report, *ext)
    return out


def model_inputs(planes: dict[str, np.ndarray], layers, meta: dict) -> dict[str, np.ndarray]:
    """Model inputs for ``layers`` from :func:`frame_planes` output: the same arrays, except
    ``normal``, which models see in screen space (a new array; ``planes`` is left as is)."""
    return {name: screen_normal_planes(planes[name], meta) if name == "normal" else planes[name]
            for name in layers}


def frame_inputs(frame: Frame, layers, report: SanitizeReport | None = None) -> dict[str, np.ndarray]:
    """The model inputs for ``layers`` as a dict name -> (1, C, H, W) float32, sanitised,
    normals in screen space.  Raises FrameError naming the frame and the missing layer."""
    return model_inputs(frame_planes(frame, layers, report), layers, frame.meta)


#: Per-sample groups holding radiance: sanitised as radiance and auto-exposed like ``color``.
RADIANCE_SAMPLE_GROUPS = ("radiance", "diffuse_radiance", "specular_radiance")


def sample_group_channels(group: str) -> int:
    """Channels of a per-sample group (stored or derived); ValueError naming the known ones."""
    from mcdenoise.runtime.frames import DERIVED_SAMPLE_GROUPS, SAMPLE_GROUPS

    if group in DERIVED_SAMPLE_GROUPS:
        return 3
    if group not in SAMPLE_GROUPS:
        raise ValueError(f"unknown per-sample group {group!r}; known: {list(SAMPLE_GROUPS) + list(DERIVED_SAMPLE_GROUPS)}")
    return SAMPLE_GROUPS[group].stop - SAMPLE_GROUPS[group].start


def sample_channels(groups, which: str) -> list[int]:
    """Channel indices of the per-sample input laid out as ``groups`` (names, in order):
    ``which`` = "radiance" (the auto-exposed ones) or "screen_xy" (the x, y of ``normal``,
    which image flips and rotations act on)."""
    out, c = [], 0
    for g in groups:
        n = sample_group_channels(g)
        if which == "radiance" and g in RADIANCE_SAMPLE_GROUPS:
            out += list(range(c, c + n))
        elif which == "screen_xy" and g == "normal":
            out += [c, c + 1]
        c += n
    return out


def sample_inputs(frame: Frame, groups, report: SanitizeReport | None = None, scale=None) -> np.ndarray:
    """The per-sample input of a model reading ``groups`` (names, in order): (1, S, F, H, W)
    float32 from ``frame.samples`` (S, H, W, F_stored), every pixel with the frame's S samples.
    Sanitised as the pixel layers are (radiance groups like ``color``, the rest non-finite ->
    :data:`NONFINITE_FILL` or 0), radiance groups times ``scale`` (the auto-exposure factor, or
    None), normals in screen space (:func:`screen_normals`).  The one definition for the
    dataset and the driver; raises FrameError when the frame has no per-sample layers."""
    from mcdenoise.runtime.frames import FrameError

    report = SanitizeReport() if report is None else report
    if frame.samples is None:
        raise FrameError(f"{frame.path or 'frame'}: this model reads per-sample data (sample<i>.* layers) and "
                         "the frame has none; render with 'mcdenoise render' (without --pixel-only) or write the "
                         "renderer's samples as sample<i>.* channels (runtime/frames.py)")
    s, h, w, _ = frame.samples.shape
    out = np.empty((1, s, sum(sample_group_channels(g) for g in groups), h, w), np.float32)
    c = 0
    for g in groups:
        arr = frame.sample_feature(g)
        if g == "normal":
            arr = screen_normals(arr, frame.meta)
        n = arr.shape[-1]
        block = out[0, :, c:c + n]
        block[...] = arr.transpose(0, 3, 1, 2)
        _sanitize_inplace(block, g in RADIANCE_SAMPLE_GROUPS, "sample " + g if g not in NONFINITE_FILL else g, report)
        if scale is not None and g in RADIANCE_SAMPLE_GROUPS:
            block *= np.float32(scale)
        c += n
    return out
