"""Temporal reprojection with a geometric consistency test: one definition for runtime and training.

The driver keeps every model's temporal state generically: after frame t-1 it stores the
model's ``next_<name>`` outputs and frame t-1's guide buffers; at frame t it calls
:func:`reproject` to warp the state along the motion vectors, testing each bilinear tap for
geometric consistency (world position and shading normal, as in WSKPN §4.1 / SVGF), and feeds
the warped state plus the resulting ``history`` mask to the model.  Training calls the same
function on torch tensors (it is differentiable w.r.t. the state), so train and test agree.

All arrays are NCHW: states (N, C, H, W); motion (N, 2, H, W) in pixels with
prev = (x, y) + motion (x right, y down); positions (N, 3, H, W) world space; normals
(N, 3, H, W) world-space unit vectors; depth (N, 1, H, W), 0 on a miss.  numpy or torch.
"""
from __future__ import annotations

import numpy as np

from runtime.transfer import xp

#: A tap is consistent when its world position lies within this fraction of the current
#: depth (≈ 8 pixel footprints at 256 px and 45° fov: loose enough for slanted surfaces,
#: tight enough to reject the background behind an edge).
POSITION_TOLERANCE = 0.05
#: ... and its normal is within acos(0.9) ≈ 26° of the current one.
NORMAL_COS_TOLERANCE = 0.9
#: Relative depth tolerance used when frames carry no world position.
DEPTH_TOLERANCE = 0.1
#: Pixels whose consistent bilinear weight sums to less than this get no history.
MIN_WEIGHT = 1e-3


def _floor(x):
    return np.floor(x) if xp(x) is np else x.floor()


def _gather(flat, idx):
    """flat (N, C, L), idx (N, 1, M) int -> (N, C, M)."""
    n, c = flat.shape[:2]
    if xp(flat) is np:
        return np.stack([np.take(flat[i], idx[i, 0], axis=1, mode="clip") for i in range(n)])
    return flat.gather(2, idx.expand(n, c, idx.shape[-1]))


def _to_index(v):
    return v.astype(np.int64) if xp(v) is np else v.long()


def _grid(motion, y_offset: int = 0):
    n, _, h, w = motion.shape
    if xp(motion) is np:
        ys, xs = np.meshgrid(np.arange(y_offset, y_offset + h, dtype=np.float32),
                             np.arange(w, dtype=np.float32), indexing="ij")
    else:
        torch = _torch()
        ys, xs = torch.meshgrid(torch.arange(y_offset, y_offset + h, dtype=motion.dtype, device=motion.device),
                                torch.arange(w, dtype=motion.dtype, device=motion.device), indexing="ij")
    return xs[None, None] + motion[:, 0:1], ys[None, None] + motion[:, 1:2]


#: numpy processes this many output rows at a time, so a band's per-tap temporaries (80 KB
#: planes at 1280 wide) stay in the core's cache.  Measured at 1280x720: 16 rows 100 ms, 32 rows
#: 124, 64 rows 139, the whole frame at once 280 (every temporary a fresh page-faulted block).
BAND_ROWS = 16


def reproject(states, motion, cur: dict, prev: dict):
    """Warp ``states`` from frame t-1 to frame t and compute the history mask.

    Args:
      states: list of (N, C_i, H, W) arrays from frame t-1 (the model's ``next_*`` outputs).
      motion: (N, 2, H, W) frame t's motion vectors, pixels.
      cur, prev: guide buffers of frames t and t-1: ``depth`` (required) and optionally
        ``position`` and ``normal`` (world space).  Position beats depth when both frames have it.

    Returns:
      (warped states list, history (N, 1, H, W) in {0, 1}).  Inconsistent or off-screen taps are
      dropped and the remaining bilinear weights renormalised; pixels with no consistent tap get
      history 0 and state 0.  numpy and torch give the same result (torch: differentiable
      w.r.t. the states; numpy: the driver's fast path, :func:`_reproject_numpy`).
    """
    use_pos = "position" in cur and "position" in prev
    use_nrm = "normal" in cur and "normal" in prev
    if xp(motion) is np:
        return _reproject_numpy(states, motion, cur, prev, use_pos, use_nrm)
    n, _, h, w = motion.shape
    # One gather per tap for every field: the guides and all states stacked along channels.
    fields = [prev["depth"]] + ([prev["position"]] if use_pos else []) + ([prev["normal"]] if use_nrm else []) + list(states)
    stacked = _torch().cat(fields, dim=1).reshape(n, sum(f.shape[1] for f in fields), h * w)
    acc, history = _reproject_rows(stacked, motion, cur, 0, h, use_pos, use_nrm)
    return _split_states(acc, states), history


def _split_states(acc, states):
    warped, c = [], 0
    for st in states:
        warped.append(acc[:, c:c + st.shape[1]])
        c += st.shape[1]
    return warped


def _reproject_numpy(states, motion, cur, prev, use_pos: bool, use_nrm: bool):
    """numpy :func:`reproject`: the arithmetic of :func:`_reproject_rows`, laid out for speed
    on the driver's CPU (1280x720, sub-pixel motion, this project's 2-vCPU machine: 205 ms
    with per-tap gathers of a stacked (C, H*W) array over 32-row bands, 100 ms this way).

    * Planar: every guide and state channel is a contiguous (H*W,) plane gathered with one 1-D
      ``np.take`` per tap, and every test is plane arithmetic.  Gathering along axis 1 of a
      (C, H*W) stack costs 2-3x more; a channels-last table makes the tests strided (20-40x
      slower per element).
    * Bands of :data:`BAND_ROWS` rows keep a band's temporaries in the core's cache.
    * A tap whose bilinear weight is 0 over a whole band (integer or zero motion: a static
      camera) is skipped: its consistent weight would be 0 anyway.
    * Serial: two threads over bands were slower here (GIL hand-offs between many short numpy
      calls), and onnxruntime's threads take the cores right after.
    """
    n, _, h, w = motion.shape
    n_state = sum(st.shape[1] for st in states)
    dtype = np.result_type(*[st.dtype for st in states]) if states else motion.dtype
    acc = np.empty((n, n_state, h, w), dtype=dtype)
    history = np.empty((n, 1, h, w), dtype=motion.dtype)
    xs = np.arange(w, dtype=motion.dtype)
    for b in range(n):
        guides = [prev["depth"][b, 0]] + ([prev["position"][b, c] for c in range(3)] if use_pos else []) \
            + ([prev["normal"][b, c] for c in range(3)] if use_nrm else [])
        guides = [np.ascontiguousarray(g).reshape(-1) for g in guides]
        planes = [np.ascontiguousarray(st[b, c]).reshape(-1) for st in states for c in range(st.shape[1])]
        for y in range(0, h, BAND_ROWS):
            y1 = min(h, y + BAND_ROWS)
            px = xs + motion[b, 0, y:y1]
            py = np.arange(y, y1, dtype=motion.dtype)[:, None] + motion[b, 1, y:y1]
            x0, y0 = np.floor(px), np.floor(py)
            fx, fy = px - x0, py - y0
            ix, iy = x0.astype(np.int64), y0.astype(np.int64)
            base = iy * w + ix
            in_x = ((ix >= 0) & (ix <= w - 1), (ix >= -1) & (ix <= w - 2))
            in_y = ((iy >= 0) & (iy <= h - 1), (iy >= -1) & (iy <= h - 2))
            cur_depth = cur["depth"][b, 0, y:y1]
            cur_hit = cur_depth > 0
            if use_pos:
                cur_pos = cur["position"][b, :, y:y1]
                tol2 = (POSITION_TOLERANCE * cur_depth) ** 2
            if use_nrm:
                cur_nrm = cur["normal"][b, :, y:y1]
            wsum = np.zeros_like(fx)
            sums = [np.zeros(fx.shape, dtype=dtype) for _ in planes]
            for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
                wgt = (fx if dx else 1 - fx) * (fy if dy else 1 - fy)
                if not wgt.any():
                    continue
                # Off-screen taps read some valid pixel (clipped flat index); ``in_x``/``in_y`` drop them.
                idx = base + (dy * w + dx)
                g = [np.take(p, idx, mode="clip") for p in guides]
                ok = in_x[dx] & in_y[dy] & cur_hit & (g[0] > 0)
                c = 1
                if use_pos:
                    d0, d1, d2 = g[1] - cur_pos[0], g[2] - cur_pos[1], g[3] - cur_pos[2]
                    ok &= (d0 * d0 + d1 * d1 + d2 * d2) <= tol2
                    c = 4
                else:
                    ok &= np.abs(g[0] - cur_depth) <= DEPTH_TOLERANCE * cur_depth
                if use_nrm:
                    ok &= (g[c] * cur_nrm[0] + g[c + 1] * cur_nrm[1] + g[c + 2] * cur_nrm[2]) >= NORMAL_COS_TOLERANCE
                wk = wgt * ok
                wsum += wk
                for s, p in zip(sums, planes):
                    s += wk * np.take(p, idx, mode="clip")
            hist = (wsum >= MIN_WEIGHT).astype(wsum.dtype)
            scale = hist / np.maximum(wsum, MIN_WEIGHT)
            for c, s in enumerate(sums):
                acc[b, c, y:y1] = s * scale
            history[b, 0, y:y1] = hist
    return _split_states(acc, states), history


def _reproject_rows(stacked, motion, cur: dict, y_offset: int, h_full: int, use_pos: bool, use_nrm: bool):
    """:func:`reproject` for output rows y_offset .. y_offset + motion.shape[2] of a frame of
    height ``h_full``; ``stacked`` (N, C, H_full * W) holds prev depth [, position][, normal],
    then the states.  Returns (warped stacked states (N, C_states, rows, W), history)."""
    is_np = xp(motion) is np
    n, _, h, w = motion.shape
    px, py = _grid(motion, y_offset)
    x0, y0 = _floor(px), _floor(py)
    fx, fy = px - x0, py - y0
    cur_depth = cur["depth"]
    cur_hit = cur_depth > 0
    if use_pos:
        tol2 = (POSITION_TOLERANCE * cur_depth) ** 2
    n_guides = 1 + 3 * use_pos + 3 * use_nrm

    def csum(a):
        return a.sum(1, keepdims=True) if is_np else a.sum(1, keepdim=True)

    wsum = 0.0
    acc = None
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        tx, ty = x0 + dx, y0 + dy
        wgt = (fx if dx else 1 - fx) * (fy if dy else 1 - fy)
        inside = (tx >= 0) & (tx <= w - 1) & (ty >= 0) & (ty <= h_full - 1)
        tx_c = tx.clip(0, w - 1) if is_np else tx.clamp(0, w - 1)
        ty_c = ty.clip(0, h_full - 1) if is_np else ty.clamp(0, h_full - 1)
        idx = _to_index(ty_c * w + tx_c).reshape(n, 1, h * w)
        taps = _gather(stacked, idx).reshape(n, stacked.shape[1], h, w)
        p_depth = taps[:, 0:1]
        c = 1
        ok = inside & cur_hit & (p_depth > 0)
        if use_pos:
            d = taps[:, c:c + 3] - cur["position"]
            c += 3
            ok = ok & (csum(d * d) <= tol2)
        else:
            ok = ok & ((p_depth - cur_depth).__abs__() <= DEPTH_TOLERANCE * cur_depth)
        if use_nrm:
            ok = ok & (csum(taps[:, c:c + 3] * cur["normal"]) >= NORMAL_COS_TOLERANCE)
        wk = wgt * (ok.astype(wgt.dtype) if is_np else ok.to(wgt.dtype))
        wsum = wsum + wk
        contrib = wk * taps[:, n_guides:]
        acc = contrib if acc is None else acc + contrib
    has = wsum >= MIN_WEIGHT
    if is_np:
        history = has.astype(wsum.dtype)
        scale = history / np.maximum(wsum, MIN_WEIGHT)
    else:
        history = has.to(wsum.dtype)
        scale = history / wsum.clamp(min=MIN_WEIGHT)
    return acc * scale, history


def _torch():
    import sys

    return sys.modules["torch"]
