"""Temporal reprojection with a geometric consistency test: one definition for runtime and training.

The driver keeps every model's temporal state generically: after frame t-1 it stores the
model's ``next_<name>`` outputs, the accumulations of the inputs the model declares
accumulated (:func:`accumulate`) and frame t-1's guide buffers; at frame t it calls
:func:`reproject` to warp the state along the motion vectors, testing each bilinear tap for
geometric consistency (world position and shading normal, as in WSKPN §4.1 / SVGF), and feeds
the warped state plus the resulting ``history`` mask to the model (an accumulated input is
blended with the frame's value in the same pass).  Training calls the same functions on torch
tensors (differentiable w.r.t. the state), so train and test agree.

All arrays are NCHW: states (N, C, H, W); motion (N, 2, H, W) in pixels with
prev = (x, y) + motion (x right, y down); positions (N, 3, H, W) world space; normals
(N, 3, H, W) world-space unit vectors; depth (N, 1, H, W), 0 on a miss.  numpy or torch.
"""
from __future__ import annotations

import numpy as np

from dataclasses import dataclass
from typing import Callable, Mapping

from mcdenoise.runtime import workers
from mcdenoise.runtime.contract import HISTORY, state_input_name, state_output_name, state_weight_name
from mcdenoise.runtime.transfer import xp

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

#: Output rows numpy processes at a time on one thread, so a band's temporaries stay near the
#: core (1280x720: 8 rows 61 ms, 16 rows 61, 24 rows 62).
BAND_ROWS = 12
#: Band height (about) when worker threads share the frame: each numpy call must do enough
#: work to pay for taking the GIL back (1280x720, 2 threads each taking 360 rows: 16-row bands
#: 49 ms, 30 rows 42, 45 rows 42, 60 rows 44, 90 rows 52).
THREADED_BAND_ROWS = 45


@dataclass(frozen=True)
class Protocol:
    """The temporal protocol of one model, the one definition of how a history is kept and fed
    back: the driver, the trainer's unroll, the bench and the export's example inputs all run
    it. It holds no arrays and imports no torch; what it does to arrays (zeros,
    :func:`reproject`, :func:`accumulate`) works on numpy arrays and torch tensors alike.

    A history is a dict ``kept`` carried from frame to frame: the model's state tensors by
    state name (from its ``next_<name>`` outputs) and the accumulated inputs by
    :meth:`accum_key`, all (N, C, H, W) in the history's exposed units.

    Per frame, on ``feeds`` (graph input name -> (N, C, H, W) array, this frame's inputs):
    :meth:`start` (the first frame of a history: zero state and history mask, accumulations
    start at the frame) or :meth:`follow` (reproject ``kept`` onto this frame, with the
    history mask; accumulated inputs replaced by their accumulations), then the model runs on
    ``feeds``, then :meth:`update` adds its state outputs to what :meth:`start` / :meth:`follow`
    returned.

    state: (name, graph input, graph output, channels) per state tensor.
    accumulate: (frame layer, graph input, alpha, history_spp) per accumulated input: the
      current frame's weight is spp / (spp + history_spp) for a frame of known spp when
      history_spp > 0 (the history counts as that many samples per pixel), else alpha
      (:meth:`alpha`).
    history: the history-mask input ("" without state).
    weights: (graph input, alpha, history_spp) per state the model blends itself: the input
      gets this frame's weight, (N, 1, 1, 1), by the same rule (:meth:`alpha`).
    """

    state: tuple[tuple[str, str, str, int], ...] = ()
    accumulate: tuple[tuple[str, str, float, float], ...] = ()
    history: str = ""
    weights: tuple[tuple[str, float, float], ...] = ()

    @classmethod
    def from_contract(cls, contract) -> "Protocol":
        """From a model file's :class:`runtime.contract.Contract`."""
        return cls(tuple((s["name"], s["input"], s["output"], int(s["channels"])) for s in contract.state),
                   tuple((a["layer"], a["input"], float(a["alpha"]), float(a.get("history_spp", 0.0)))
                         for a in contract.accumulate),
                   contract.history,
                   tuple((s["weight_input"], float(s["alpha"]), float(s.get("history_spp", 0.0)))
                         for s in contract.state if "weight_input" in s))

    @classmethod
    def from_spec(cls, state_channels: Mapping[str, int], accumulate=(), weights: Mapping | None = None) -> "Protocol":
        """From a model spec's parts: {state name: channels}, (layer, alpha, history_spp) per
        accumulated layer (its graph input carries its name) and {state name: (alpha,
        history_spp)} per state the model blends with a fed weight, with the contract's input
        and output names."""
        state = tuple((n, state_input_name(n), state_output_name(n), int(c)) for n, c in state_channels.items())
        return cls(state, tuple((layer, layer, float(alpha), float(hs)) for layer, alpha, hs in accumulate),
                   HISTORY if state else "",
                   tuple((state_weight_name(n), float(a), float(hs)) for n, (a, hs) in (weights or {}).items()))

    @staticmethod
    def alpha(entry: tuple, spp=None):
        """The current frame's weight of one ``accumulate`` entry: spp / (spp + history_spp)
        when the entry has a history_spp and ``spp`` is known (> 0), else its fixed alpha.

        spp: None or 0 (unknown: a frame without per-sample data or an spp in its metadata),
        an int, or per batch item a torch / numpy (N,) integer array, for which the weight is
        (N, 1, 1, 1) (items of unknown spp get the fixed alpha)."""
        _, _, alpha, history_spp = entry
        if not history_spp or spp is None:
            return alpha
        if isinstance(spp, (int, np.integer)):
            return float(spp) / (spp + history_spp) if spp > 0 else alpha
        n = spp.reshape(-1, 1, 1, 1) * 1.0           # numpy or torch, no torch import here
        if isinstance(n, np.ndarray):
            n = n.astype(np.float32)
        return alpha + (n > 0) * (n / (n + history_spp) - alpha)

    @property
    def temporal(self) -> bool:
        """Whether anything is kept between frames."""
        return bool(self.state or self.accumulate)

    @property
    def inputs(self) -> tuple[str, ...]:
        """Graph inputs the protocol fills: the state inputs, the history mask, the weights."""
        return tuple(s[1] for s in self.state) + ((self.history,) if self.state else ()) + tuple(w[0] for w in self.weights)

    def _weigh(self, feeds: dict, like, spp) -> None:
        """Each state weight input: this frame's weight (:meth:`alpha`) as (N, 1, 1, 1)."""
        for inp, alpha, hs in self.weights:
            a = self.alpha(("", "", alpha, hs), spp)
            n = like.shape()[0] if callable(like.shape) else like.shape[0]   # an OrtValue's shape is a method
            feeds[inp] = _zeros(like, (n, 1, 1, 1)) + a

    @staticmethod
    def accum_key(graph_input: str) -> str:
        """Key of an accumulated input in ``kept`` (apart from the state names)."""
        return "accumulate:" + graph_input

    def start(self, feeds: dict, like, spp=None) -> dict:
        """The first frame of a history: zero state inputs and history mask into ``feeds``
        (shaped and typed like ``like``, an (N, C, H, W) input of this frame); returns the
        accumulations kept so far (each starts at the frame itself, as :func:`accumulate`
        does with history 0)."""
        n, _, h, w = like.shape
        for _, inp, _, ch in self.state:
            feeds[inp] = _zeros(like, (n, ch, h, w))
        if self.state:
            feeds[self.history] = _zeros(like, (n, 1, h, w))
        self._weigh(feeds, like, spp)
        return {self.accum_key(inp): feeds[inp] for _, inp, _, _ in self.accumulate}

    def follow(self, feeds: dict, kept: dict, motion, cur: dict, prev: dict,
               contiguous: Callable = lambda a: a, reproject_fn: Callable | None = None, spp=None,
               **reproject_args) -> dict:
        """A frame that continues the history ``kept`` (from :meth:`update`): its state and
        accumulations reprojected along ``motion`` (N, 2, H, W) with the consistency test on
        the guides ``cur`` / ``prev`` (:func:`reproject`, which gets ``reproject_args``), put
        into ``feeds`` with the history mask; each accumulated input becomes its
        accumulation. ``contiguous`` prepares each array fed (the driver makes them
        contiguous float32); ``reproject_fn`` replaces :func:`reproject` with what computes the
        same (the prelude graph, :class:`runtime.prelude.PreludeGraph`). ``spp``: this frame's
        samples per pixel (per item of a batch; see :meth:`alpha`). Returns the accumulations
        to keep."""
        keys = [s[0] for s in self.state] + [self.accum_key(a[1]) for a in self.accumulate]
        blend = [None] * len(self.state) + [(feeds[a[1]], self.alpha(a, spp)) for a in self.accumulate]
        warped, history = (reproject_fn or reproject)([kept[k] for k in keys], motion, cur, prev, blend=blend,
                                                      **reproject_args)
        for (_, inp, _, _), arr in zip(self.state, warped):
            feeds[inp] = contiguous(arr)
        if self.state:
            feeds[self.history] = contiguous(history)
        self._weigh(feeds, history, spp)
        out = {}
        for (_, inp, _, _), arr in zip(self.accumulate, warped[len(self.state):]):
            feeds[inp] = out[self.accum_key(inp)] = contiguous(arr)
        return out

    def update(self, kept: dict, outputs: Mapping, keep: Callable = lambda a: a) -> dict:
        """The history after this frame: the accumulations from :meth:`start` / :meth:`follow`
        plus the model's state outputs (graph output name -> array), each through ``keep``
        (the driver zeroes non-finite values there)."""
        return {**kept, **{name: keep(outputs[out]) for name, _, out, _ in self.state}}


def _zeros(like, shape):
    """Zeros of ``shape`` with ``like``'s array type, dtype and device (float32 numpy for an
    onnxruntime value: onnxruntime copies it where it is bound)."""
    if isinstance(like, np.ndarray) or not hasattr(like, "new_zeros"):
        return np.zeros(shape, getattr(like, "dtype", np.float32))
    return like.new_zeros(shape)


def accumulate(current, prev, history, alpha: float):
    """Exponential moving average with the reprojected history (WSKPN §4.1, NBG §4.6): the one
    definition, for the driver, the trainer and the models' in-graph temporal stages.

    current, prev: (N, C, H, W) linear HDR (numpy or torch); history: (N, 1, H, W) in [0, 1];
    alpha: the current frame's weight.  Returns history·(α·current + (1−α)·prev) +
    (1−history)·current.  Where history is 0, ``prev`` is ignored (it must be finite, e.g. 0).
    """
    # The broadcast (N, 1, H, W) factor goes second: onnxruntime's Mul is slower when its
    # first input is the broadcast one (the stage at 720p, four paired runs: 6.1-8.2 ms that
    # way, 5.2-6.3 ms this way; torch 3.4-5.4 ms).
    return current + (prev - current) * (history * _keep(alpha, history))


def _keep(alpha: float, like):
    """1 − α in ``like``'s float type (numpy computes a Python float in float64 otherwise)."""
    return np.float32(1.0 - alpha) if isinstance(like, np.ndarray) and like.dtype == np.float32 else 1.0 - alpha


def reproject(states, motion, cur: dict, prev: dict, threads: int = 1, blend=None):
    """Warp ``states`` from frame t-1 to frame t and compute the history mask.

    Args:
      states: list of (N, C_i, H, W) arrays from frame t-1 (the model's ``next_*`` outputs).
      motion: (N, 2, H, W) frame t's motion vectors, pixels.
      cur, prev: guide buffers of frames t and t-1: ``depth`` (required) and optionally
        ``position`` and ``normal`` (world space).  Position beats depth when both frames have it.
      threads: numpy only: worker threads that each take a share of the rows
        (:mod:`runtime.workers`); the result is the same for any count.
      blend: None, or per state None or (current (N, C_i, H, W), alpha): that state is returned
        as :func:`accumulate` (current, warped, history, alpha) (numpy: computed band by band
        while the warped values are in cache, to the bit the same).

    Returns:
      (warped states list, history (N, 1, H, W) in {0, 1}).  Inconsistent or off-screen taps are
      dropped and the remaining bilinear weights renormalised; pixels with no consistent tap get
      history 0 and state 0.  numpy and torch give the same result (torch: differentiable
      w.r.t. the states; numpy: the driver's fast path, :func:`_reproject_numpy`).
    """
    use_pos = "position" in cur and "position" in prev
    use_nrm = "normal" in cur and "normal" in prev
    blend = list(blend) if blend is not None else [None] * len(states)
    if len(blend) != len(states):
        raise ValueError(f"blend: {len(blend)} entries for {len(states)} states")
    if xp(motion) is np:
        return _reproject_numpy(states, motion, cur, prev, use_pos, use_nrm, threads, blend)
    n, _, h, w = motion.shape
    # One gather per tap for every field: the guides and all states stacked along channels.
    fields = ([prev["depth"]] + ([prev["position"]] if use_pos else []) + ([prev["normal"]] if use_nrm else [])
              + list(states))
    stacked = _torch().cat(fields, dim=1).reshape(n, sum(f.shape[1] for f in fields), h * w)
    acc, history = _reproject_rows(stacked, motion, cur, 0, h, use_pos, use_nrm)
    warped = [st if b is None else accumulate(b[0], st, history, b[1])
              for st, b in zip(_split_states(acc, states), blend)]
    return warped, history


def _split_states(acc, states):
    warped, c = [], 0
    for st in states:
        warped.append(acc[:, c:c + st.shape[1]])
        c += st.shape[1]
    return warped


def _reproject_numpy(states, motion, cur, prev, use_pos: bool, use_nrm: bool, threads: int = 1, blend=()):
    """numpy :func:`reproject`: the arithmetic of :func:`_reproject_rows`, laid out for speed on
    the driver's CPU (1280x720, sub-pixel motion, 2 vCPUs: 165 ms with per-tap gathers of a
    stacked (C, H*W) array, 42 ms as below).

    * Planar: every guide and state channel is a contiguous (H*W,) plane gathered with one 1-D
      ``np.take`` per band (all four taps at once; gathering along axis 1 of a (C, H*W) stack
      costs 2-3x more, a channels-last table makes the tests strided).
    * Taps stacked (4, rows, W): a quarter of the numpy calls and of the GIL hand-offs.
    * Bands of rows keep a band's temporaries near the core; they are preallocated per worker.
    * A tap whose bilinear weight is 0 over a whole band (integer or zero motion) is skipped.
    * With ``threads`` > 1 each thread takes one contiguous share of the rows in bands of about
      :data:`THREADED_BAND_ROWS` rows (numpy releases the GIL inside each call).
    * A blended state (:func:`accumulate`) is blended band by band while its warped values are
      in cache (720p, 3 channels, 2 threads: +2 ms instead of a 6 ms stage in the graph).
    """
    n, _, h, w = motion.shape
    n_state = sum(st.shape[1] for st in states)
    dtype = np.result_type(*[st.dtype for st in states]) if states else motion.dtype
    acc = np.empty((n, n_state, h, w), dtype)
    history = np.empty((n, 1, h, w), motion.dtype)
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
        # Per state channel: (current plane, 1 − α) when blended, else None.
        mix = [None if bl is None else (bl[0][b, c], _keep(bl[1], acc))
               for st, bl in zip(states, blend or [None] * len(states)) for c in range(st.shape[1])]
        args = (b, guides, planes, mix, motion, cur, use_pos, use_nrm, acc, history)
        jobs = [(*args, y, min(h, y + share), band) for y in range(0, h, share)]
        workers.run_all(_reproject_band_rows, jobs, threads)
    return _split_states(acc, states), history


#: Bilinear taps (dx, dy) in the order every path sums them.
_TAPS = ((0, 0), (1, 0), (0, 1), (1, 1))


def _reproject_band_rows(b, guides, planes, mix, motion, cur, use_pos, use_nrm, acc, history,
                         y_start: int, y_end: int, band: int) -> None:
    """Rows ``y_start`` .. ``y_end`` of image ``b`` for :func:`_reproject_numpy`, ``band`` rows
    at a time, into ``acc`` and ``history``; ``guides`` and ``planes``: flat previous guide and
    state planes of image ``b``; ``mix``: per plane None or (current (H, W) plane, 1 − α) to
    blend it (:func:`accumulate`).  The taps of a band are stacked, (taps, rows, W), so each
    gather and test is one numpy call for all four taps."""
    _, _, h, w = motion.shape
    ftype = motion.dtype
    dtype = acc.dtype
    xs = np.arange(w, dtype=ftype)
    rows = min(band, y_end - y_start)
    buf = lambda k, dt=ftype: np.empty((k, rows, w), dtype=dt)  # noqa: E731
    fxs, fys = buf(2), buf(2)              # bilinear factors [1 - f, f] along x and y
    wgt, t0, t1, t2, tap = buf(4), buf(4), buf(4), buf(4), buf(4, dtype)
    ok, tmp_ok = buf(4, bool), buf(4, bool)
    idx = buf(4, np.int64)
    g = [buf(4) for _ in guides]
    wsum = np.empty((rows, w), ftype)
    gain = np.empty((rows, w), dtype)         # history·(1 − α) of a blended plane
    offsets = np.array([dy * w + dx for dx, dy in _TAPS], np.int64)[:, None, None]
    for y in range(y_start, y_end, band):
        y1 = min(y_end, y + band)
        r = y1 - y
        # Clamped just off-screen (NaN -> -2): far or broken motion vectors must give
        # small indices (np.take's "wrap" steps through huge ones one period at a time).
        px = np.fmin(np.fmax(xs + motion[b, 0, y:y1], -2), w + 1)
        py = np.fmin(np.fmax(np.arange(y, y1, dtype=ftype)[:, None] + motion[b, 1, y:y1], -2), h + 1)
        x0, y0 = np.floor(px), np.floor(py)
        fx, fy = fxs[:, :r], fys[:, :r]
        np.subtract(px, x0, out=fx[1])
        np.subtract(py, y0, out=fy[1])
        np.subtract(1, fx[1], out=fx[0])
        np.subtract(1, fy[1], out=fy[0])
        # A tap whose bilinear weight is 0 over the whole band (integer motion) is skipped:
        # its consistent weight would be 0 anyway.
        taps = [k for k, (dx, dy) in enumerate(_TAPS)
                if (dx == 0 or fx[1].any()) and (dy == 0 or fy[1].any())]
        n_taps = len(taps)
        ix, iy = x0.astype(np.int64), y0.astype(np.int64)
        cur_depth = cur["depth"][b, 0, y:y1]
        cur_hit = cur_depth > 0
        # Tap inside the frame: 0 <= ix + dx < w as one unsigned compare (a negative index
        # wraps to a huge unsigned one); likewise in y, where a missed current pixel fails too.
        in_x = (ix.view(np.uint64) < w, (ix + 1).view(np.uint64) < w)
        in_y = ((iy.view(np.uint64) < h) & cur_hit, ((iy + 1).view(np.uint64) < h) & cur_hit)
        sl = (slice(0, n_taps), slice(0, r))
        wk, o, to, ik = wgt[sl], ok[sl], tmp_ok[sl], idx[sl]
        a, c2, d = t0[sl], t1[sl], t2[sl]
        for j, k in enumerate(taps):
            dx, dy = _TAPS[k]
            np.multiply(fx[dx], fy[dy], out=wk[j])
            np.logical_and(in_x[dx], in_y[dy], out=o[j])
        # Off-screen taps read some valid pixel (the flat index wraps: "wrap" gathers
        # faster than "clip"); ``in_x`` / ``in_y`` drop them.
        np.add(iy * w + ix, offsets if n_taps == 4 else offsets[taps], out=ik)
        gk = [np.take(p, ik, mode="wrap", out=q[sl]) for p, q in zip(guides, g)]
        np.greater(gk[0], 0, out=to)
        o &= to
        c = 1
        if use_pos:
            cur_pos = cur["position"][b, :, y:y1]
            np.subtract(gk[1], cur_pos[0], out=a)
            np.multiply(a, a, out=a)
            for j in (1, 2):
                np.subtract(gk[1 + j], cur_pos[j], out=d)
                np.multiply(d, d, out=d)
                a += d
            np.less_equal(a, (POSITION_TOLERANCE * cur_depth) ** 2, out=to)
            o &= to
            c = 4
        else:
            np.subtract(gk[0], cur_depth, out=a)
            np.abs(a, out=a)
            np.less_equal(a, DEPTH_TOLERANCE * cur_depth, out=to)
            o &= to
        if use_nrm:
            cur_nrm = cur["normal"][b, :, y:y1]
            np.multiply(gk[c], cur_nrm[0], out=c2)
            for j in (1, 2):
                np.multiply(gk[c + j], cur_nrm[j], out=d)
                c2 += d
            np.greater_equal(c2, NORMAL_COS_TOLERANCE, out=to)
            o &= to
        wk *= o
        ws = _sum_taps(wk, wsum[:r])
        hist = (ws >= MIN_WEIGHT).astype(ftype)
        scale = hist / np.maximum(ws, MIN_WEIGHT)
        tk = tap[sl]
        gain_for = None  # the 1 − α that gain currently holds
        for c, (p, mx) in enumerate(zip(planes, mix)):
            np.take(p, ik, mode="wrap", out=tk)
            tk *= wk
            out = acc[b, c, y:y1]
            np.multiply(_sum_taps(tk, out), scale, out=out)
            if mx is not None:
                # accumulate(): current + (warped − current)·(history·(1 − α)), same op order
                current, keep = mx
                if gain_for is not keep:
                    np.multiply(hist, keep, out=gain[:r])
                    gain_for = keep
                cur_band = current[y:y1]
                out -= cur_band
                out *= gain[:r]
                out += cur_band
        history[b, 0, y:y1] = hist


def _sum_taps(stack, out):
    """``out`` = stack[0] + stack[1] + ..., summed in tap order (as the torch path sums)."""
    if len(stack) == 1:
        out[...] = stack[0]
        return out
    np.add(stack[0], stack[1], out=out)
    for s in stack[2:]:
        out += s
    return out


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
