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

import os

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


#: numpy processes this many output rows at a time: the per-tap temporaries of a band stay in
#: cache, which at 720p roughly halves the time of whole-frame array ops (memory-bound).
BAND_ROWS = 32


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
      history 0 and state 0.
    """
    is_np = xp(motion) is np
    n, _, h, w = motion.shape
    use_pos = "position" in cur and "position" in prev
    use_nrm = "normal" in cur and "normal" in prev
    # One gather per tap for every field: the guides and all states stacked along channels.
    fields = [prev["depth"]] + ([prev["position"]] if use_pos else []) + ([prev["normal"]] if use_nrm else []) + list(states)
    sizes = [f.shape[1] for f in fields]
    stacked = (np.concatenate(fields, axis=1) if is_np else _torch().cat(fields, dim=1)).reshape(n, sum(sizes), h * w)
    if not is_np:
        acc, history = _reproject_rows(stacked, motion, cur, 0, h, use_pos, use_nrm)
    else:
        # Bands write straight into the outputs: no whole-frame concatenation afterwards.
        acc = np.empty((n, sum(st.shape[1] for st in states), h, w), dtype=stacked.dtype)
        history = np.empty((n, 1, h, w), dtype=motion.dtype)

        def band(y):
            a, hi = _reproject_rows(stacked, motion[:, :, y:y + BAND_ROWS],
                                    {k: v[:, :, y:y + BAND_ROWS] for k, v in cur.items()}, y, h, use_pos, use_nrm)
            acc[:, :, y:y + BAND_ROWS] = a
            history[:, :, y:y + BAND_ROWS] = hi

        if h * w >= PARALLEL_MIN_PIXELS:
            list(_pool().map(band, range(0, h, BAND_ROWS)))
        else:  # small frames: thread hand-offs would cost more than they save
            for y in range(0, h, BAND_ROWS):
                band(y)
    warped, c = [], 0
    for st in states:
        warped.append(acc[:, c:c + st.shape[1]])
        c += st.shape[1]
    return warped, history


#: Frames with at least this many pixels run their bands on the thread pool.  Measured at
#: 720p: 205 -> 125 ms on two quiet cores of a 16-core Xeon, no change (143 vs 154 ms, noise)
#: on this project's 2-vCPU machine; below ~512K pixels the hand-offs cost more than they save
#: (160x120: 3.3 ms serial, 6.7 ms pooled).
PARALLEL_MIN_PIXELS = 1 << 19
_POOL = None


def _pool():
    """Threads for the numpy bands: numpy releases the GIL in gathers and element-wise ops, so
    bands run in parallel on every core (the driver's other work is onnxruntime's, not ours)."""
    global _POOL
    if _POOL is None:
        from concurrent.futures import ThreadPoolExecutor

        _POOL = ThreadPoolExecutor(max_workers=max(1, len(os.sched_getaffinity(0))), thread_name_prefix="reproject")
    return _POOL


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
