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
from runtime.workers import run_all

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


#: numpy processes this many output rows at a time, so a band's per-tap temporaries (80 KB
#: planes at 1280 wide) stay in the core's cache.  Measured at 1280x720 (before the buffers
#: were reused): 16 rows 100 ms, 32 rows 124, 64 rows 139, the whole frame at once 280.
BAND_ROWS = 16
#: Band height (about) when worker threads share the frame: each numpy call must do enough
#: work to pay for taking the GIL back.  1280x720, 2 threads each taking 360 rows, this
#: machine's 2 cores: 16-row bands 81 ms (one thread: 77), 60 rows 57, 72 rows 56, 90 rows
#: 54, 120 rows 57.
THREADED_BAND_ROWS = 90


def reproject(states, motion, cur: dict, prev: dict, threads: int = 1):
    """Warp ``states`` from frame t-1 to frame t and compute the history mask.

    Args:
      states: list of (N, C_i, H, W) arrays from frame t-1 (the model's ``next_*`` outputs).
      motion: (N, 2, H, W) frame t's motion vectors, pixels.
      cur, prev: guide buffers of frames t and t-1: ``depth`` (required) and optionally
        ``position`` and ``normal`` (world space).  Position beats depth when both frames have it.
      threads: numpy only: worker threads that each take a share of the rows
        (:mod:`runtime.workers`); the result is the same for any count.

    Returns:
      (warped states list, history (N, 1, H, W) in {0, 1}).  Inconsistent or off-screen taps are
      dropped and the remaining bilinear weights renormalised; pixels with no consistent tap get
      history 0 and state 0.  numpy and torch give the same result (torch: differentiable
      w.r.t. the states; numpy: the driver's fast path, :func:`_reproject_numpy`).
    """
    use_pos = "position" in cur and "position" in prev
    use_nrm = "normal" in cur and "normal" in prev
    if xp(motion) is np:
        return _reproject_numpy(states, motion, cur, prev, use_pos, use_nrm, threads)
    n, _, h, w = motion.shape
    # One gather per tap for every field: the guides and all states stacked along channels.
    fields = ([prev["depth"]] + ([prev["position"]] if use_pos else []) + ([prev["normal"]] if use_nrm else [])
              + list(states))
    stacked = _torch().cat(fields, dim=1).reshape(n, sum(f.shape[1] for f in fields), h * w)
    acc, history = _reproject_rows(stacked, motion, cur, 0, h, use_pos, use_nrm)
    return _split_states(acc, states), history


def _split_states(acc, states):
    warped, c = [], 0
    for st in states:
        warped.append(acc[:, c:c + st.shape[1]])
        c += st.shape[1]
    return warped


def _reproject_numpy(states, motion, cur, prev, use_pos: bool, use_nrm: bool, threads: int = 1):
    """numpy :func:`reproject`: the arithmetic of :func:`_reproject_rows`, laid out for speed
    on the driver's CPU (1280x720, sub-pixel motion, this project's 2-vCPU machine: 165 ms
    with per-tap gathers of a stacked (C, H*W) array over 32-row bands on two threads, 125 ms
    planar as below, 100 ms with the preallocated buffers, 58 ms with 64-row bands split
    between two threads on a quieter day that measured 77 ms for one thread).

    * Planar: every guide and state channel is a contiguous (H*W,) plane gathered with one 1-D
      ``np.take`` per tap, and every test is plane arithmetic.  Gathering along axis 1 of a
      (C, H*W) stack costs 2-3x more; a channels-last table makes the tests strided (20-40x
      slower per element).
    * Bands of rows keep a band's temporaries in the core's cache, and the temporaries are
      preallocated per worker and reused (``out=``): no allocation per operation.
    * A tap whose bilinear weight is 0 over a whole band (integer or zero motion: a static
      camera) is skipped: its consistent weight would be 0 anyway.
    * With ``threads`` > 1, each thread takes one contiguous share of the rows in bands of
      about :data:`THREADED_BAND_ROWS` rows (numpy releases the GIL inside each call; small
      bands made two threads slower than one).
    """
    n, _, h, w = motion.shape
    n_state = sum(st.shape[1] for st in states)
    dtype = np.result_type(*[st.dtype for st in states]) if states else motion.dtype
    acc = np.empty((n, n_state, h, w), dtype=dtype)
    history = np.empty((n, 1, h, w), dtype=motion.dtype)
    band = THREADED_BAND_ROWS if threads > 1 else BAND_ROWS
    # Each thread takes an equal share of the rows, cut into equal bands of about ``band``
    # rows (whole 64-row bands split 720 rows 384/336: 4 ms slower).  No result depends on
    # the partition: every pixel sums its own four taps in the same order (a skipped tap
    # would add 0).
    share = -(-h // max(1, threads))
    band = -(-share // max(1, round(share / band)))
    for b in range(n):
        guides = [prev["depth"][b, 0]] + ([prev["position"][b, c] for c in range(3)] if use_pos else []) \
            + ([prev["normal"][b, c] for c in range(3)] if use_nrm else [])
        guides = [np.ascontiguousarray(p).reshape(-1) for p in guides]
        planes = [np.ascontiguousarray(st[b, c]).reshape(-1) for st in states for c in range(st.shape[1])]
        args = (b, guides, planes, motion, cur, use_pos, use_nrm, acc, history)
        run_all(_reproject_band_rows, [(*args, y, min(h, y + share), band) for y in range(0, h, share)], threads)
    return _split_states(acc, states), history


def _reproject_band_rows(b, guides, planes, motion, cur, use_pos, use_nrm, acc, history,
                         y_start: int, y_end: int, band: int) -> None:
    """Rows ``y_start`` .. ``y_end`` of image ``b`` for :func:`_reproject_numpy`, ``band`` rows
    at a time, into ``acc`` and ``history``; ``guides`` and ``planes``: flat previous guide and
    state planes of image ``b``."""
    _, _, h, w = motion.shape
    ftype = motion.dtype
    dtype = acc.dtype
    xs = np.arange(w, dtype=ftype)
    rows = min(band, y_end - y_start)
    buf = lambda dt=ftype: np.empty((rows, w), dtype=dt)  # noqa: E731
    wgt, gx, gy, wsum, t0, t1, t2 = (buf() for _ in range(7))
    ok, tmp_ok = buf(bool), buf(bool)
    idx = buf(np.int64)
    g = [buf() for _ in guides]
    sums = [buf(dtype) for _ in planes]
    tap = buf(dtype)
    for y in range(y_start, y_end, band):
        y1 = min(y_end, y + band)
        r = y1 - y
        sl = (slice(0, r), slice(None))
        # Clamped just off-screen (NaN -> -2): far or broken motion vectors must give
        # small indices (np.take's "wrap" steps through huge ones one period at a time).
        px = np.fmin(np.fmax(xs + motion[b, 0, y:y1], -2), w + 1)
        py = np.fmin(np.fmax(np.arange(y, y1, dtype=ftype)[:, None] + motion[b, 1, y:y1], -2), h + 1)
        x0, y0 = np.floor(px), np.floor(py)
        fx, fy = px - x0, py - y0
        np.subtract(1, fx, out=gx[sl])
        np.subtract(1, fy, out=gy[sl])
        ix, iy = x0.astype(np.int64), y0.astype(np.int64)
        base = iy * w + ix
        cur_depth = cur["depth"][b, 0, y:y1]
        cur_hit = cur_depth > 0
        in_x = ((ix >= 0) & (ix <= w - 1), (ix >= -1) & (ix <= w - 2))
        in_y = (((iy >= 0) & (iy <= h - 1)) & cur_hit, ((iy >= -1) & (iy <= h - 2)) & cur_hit)
        if use_pos:
            cur_pos = cur["position"][b, :, y:y1]
            tol2 = (POSITION_TOLERANCE * cur_depth) ** 2
        else:
            tol_d = DEPTH_TOLERANCE * cur_depth
        if use_nrm:
            cur_nrm = cur["normal"][b, :, y:y1]
        ws = wsum[sl]
        ws.fill(0)
        for s in sums:
            s[sl].fill(0)
        for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
            wk = wgt[sl]
            np.multiply(fx if dx else gx[sl], fy if dy else gy[sl], out=wk)
            if not wk.any():
                continue
            # Off-screen taps read some valid pixel (the flat index wraps: "wrap" gathers
            # faster than "clip"); ``in_x`` / ``in_y`` drop them.
            ik = idx[sl]
            np.add(base, dy * w + dx, out=ik)
            gk = [np.take(p, ik, mode="wrap", out=q[sl]) for p, q in zip(guides, g)]
            o, to = ok[sl], tmp_ok[sl]
            np.logical_and(in_x[dx], in_y[dy], out=o)
            np.greater(gk[0], 0, out=to)
            o &= to
            a, c2, d = t0[sl], t1[sl], t2[sl]
            c = 1
            if use_pos:
                np.subtract(gk[1], cur_pos[0], out=a)
                np.multiply(a, a, out=a)
                for j in (1, 2):
                    np.subtract(gk[1 + j], cur_pos[j], out=d)
                    np.multiply(d, d, out=d)
                    a += d
                np.less_equal(a, tol2, out=to)
                o &= to
                c = 4
            else:
                np.subtract(gk[0], cur_depth, out=a)
                np.abs(a, out=a)
                np.less_equal(a, tol_d, out=to)
                o &= to
            if use_nrm:
                np.multiply(gk[c], cur_nrm[0], out=c2)
                for j in (1, 2):
                    np.multiply(gk[c + j], cur_nrm[j], out=d)
                    c2 += d
                np.greater_equal(c2, NORMAL_COS_TOLERANCE, out=to)
                o &= to
            wk *= o
            ws += wk
            tk = tap[sl]
            for s, p in zip(sums, planes):
                np.take(p, ik, mode="wrap", out=tk)
                tk *= wk
                s[sl] += tk
        hist = (ws >= MIN_WEIGHT).astype(ftype)
        scale = hist / np.maximum(ws, MIN_WEIGHT)
        for c, s in enumerate(sums):
            np.multiply(s[sl], scale, out=acc[b, c, y:y1])
        history[b, 0, y:y1] = hist


def _reproject_rows(stacked, motion, cur: dict, y_offset: int, h_full: int, use_pos: bool, use_nrm: bool):
    """torch :func:`reproject` for output rows y_offset .. y_offset + motion.shape[2] of a frame
    of height ``h_full``; ``stacked`` (N, C, H_full * W) holds prev depth [, position][, normal],
    then the states.  Returns (warped stacked states (N, C_states, rows, W), history).  The
    numpy twin, :func:`_reproject_numpy`, must compute the same."""
    torch = _torch()
    n, _, h, w = motion.shape
    ys, xs = torch.meshgrid(torch.arange(y_offset, y_offset + h, dtype=motion.dtype, device=motion.device),
                            torch.arange(w, dtype=motion.dtype, device=motion.device), indexing="ij")
    # As in the numpy path: positions clamped just off-screen, NaN -> -2 (off-screen).
    px = (xs[None, None] + motion[:, 0:1]).nan_to_num(nan=-2.0).clamp(-2, w + 1)
    py = (ys[None, None] + motion[:, 1:2]).nan_to_num(nan=-2.0).clamp(-2, h_full + 1)
    x0, y0 = px.floor(), py.floor()
    fx, fy = px - x0, py - y0
    cur_depth = cur["depth"]
    cur_hit = cur_depth > 0
    if use_pos:
        tol2 = (POSITION_TOLERANCE * cur_depth) ** 2
    n_guides = 1 + 3 * use_pos + 3 * use_nrm
    n_fields = stacked.shape[1]
    wsum = 0.0
    acc = None
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        tx, ty = x0 + dx, y0 + dy
        wgt = (fx if dx else 1 - fx) * (fy if dy else 1 - fy)
        inside = (tx >= 0) & (tx <= w - 1) & (ty >= 0) & (ty <= h_full - 1)
        idx = (ty.clamp(0, h_full - 1) * w + tx.clamp(0, w - 1)).long().reshape(n, 1, h * w)
        taps = stacked.gather(2, idx.expand(n, n_fields, h * w)).reshape(n, n_fields, h, w)
        p_depth = taps[:, 0:1]
        c = 1
        ok = inside & cur_hit & (p_depth > 0)
        if use_pos:
            d = taps[:, c:c + 3] - cur["position"]
            c += 3
            ok = ok & ((d * d).sum(1, keepdim=True) <= tol2)
        else:
            ok = ok & ((p_depth - cur_depth).abs() <= DEPTH_TOLERANCE * cur_depth)
        if use_nrm:
            ok = ok & ((taps[:, c:c + 3] * cur["normal"]).sum(1, keepdim=True) >= NORMAL_COS_TOLERANCE)
        wk = wgt * ok.to(wgt.dtype)
        wsum = wsum + wk
        contrib = wk * taps[:, n_guides:]
        acc = contrib if acc is None else acc + contrib
    history = (wsum >= MIN_WEIGHT).to(wsum.dtype)
    return acc * (history / wsum.clamp(min=MIN_WEIGHT)), history


def _torch():
    import sys

    return sys.modules["torch"]
