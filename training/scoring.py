"""Scores of the measuring side, one definition each: :func:`score` (every metric of
:mod:`training.metrics` over frames, pooled the same way for ``evaluate``, ``bench`` and
``stress``), :func:`run_methods` (methods over sequences, then scored) and
:func:`pareto_front` (the quality-vs-time front of the bench chart)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from mcdenoise.training import metrics
from mcdenoise.runtime.frames import Frame
from mcdenoise.training.testsets import at_spp

#: Metric columns, in table order (TRMAE is per sequence, the others over all frames);
#: "wte" (:func:`training.metrics.warped_temporal_error`) needs the frames' motion and guides.
METRICS = ("psnr", "ssim", "flip", "smape", "relmse", "trmae", "wte")


def score(outs: list[np.ndarray], refs: list[np.ndarray], seq_lengths: list[int],
          which: tuple[str, ...] = METRICS, frames: list[Frame] | None = None) -> dict:
    """Metrics ``which`` (default all of :data:`METRICS`) of frames ``outs`` against ``refs``
    ((H, W, 3) linear radiance; flat lists, sequences back to back with lengths
    ``seq_lengths``): {metric: value, ..., frames}.

    Frames may differ in size (sequences of several sizes, a sequence that changes
    resolution); every metric then pools as it does over frames of one size: PSNR, SMAPE and
    relMSE over all pixels, SSIM over all valid window positions, FLIP over all pixels, TRMAE
    over the runs of equal-sized frames within each sequence (mean over runs). The warped
    temporal error ("wte") pools over every sequence (a ratio of sums) when ``frames`` (the
    input frames, aligned with ``outs``) are given, else it is None."""
    if len(outs) != len(refs) or sum(seq_lengths) != len(outs):
        raise ValueError(f"score: {len(outs)} outputs, {len(refs)} references, sequences of "
                         f"{sum(seq_lengths)} frames")
    outs = [np.asarray(x, np.float32) for x in outs]
    refs = [np.asarray(x, np.float32) for x in refs]
    for i, (a, b) in enumerate(zip(outs, refs)):
        if a.shape != b.shape:
            raise ValueError(f"score: frame {i} is {a.shape}, its reference {b.shape}")
    unknown = set(which) - set(METRICS)
    if unknown:
        raise ValueError(f"score: unknown metric(s) {sorted(unknown)}; known: {METRICS}")
    o, r = metrics.pixels(outs), metrics.pixels(refs)
    res = {k: getattr(metrics, k)(o, r) for k in ("psnr", "smape", "relmse") if k in which}
    # Windowed metrics per frame size, weighted by what each one averages over.
    by_size: dict[tuple, list[int]] = {}
    for i, x in enumerate(outs):
        by_size.setdefault(x.shape, []).append(i)
    parts = {k: [] for k in ("ssim", "flip") if k in which}   # (value, how many it averages over)
    for (h, w, _), idx in by_size.items() if parts else ():
        so, sr = np.stack([outs[i] for i in idx]), np.stack([refs[i] for i in idx])
        win = (h - metrics.SSIM_WINDOW + 1) * (w - metrics.SSIM_WINDOW + 1)
        if "ssim" in parts:
            parts["ssim"].append((metrics.ssim(so, sr), len(idx) * win))
        if "flip" in parts:
            parts["flip"].append((metrics.flip(so, sr), len(idx) * h * w))
    for k, vw in parts.items():
        res[k] = vw[0][0] if len(vw) == 1 else float(sum(v * n for v, n in vw) / sum(n for _, n in vw))
    trm, start = [], 0
    for n in seq_lengths if "trmae" in which else ():
        run = start
        for i in range(start, start + n + 1):
            if i == start + n or outs[i].shape != outs[run].shape:
                if i - run >= 2:
                    trm.append(metrics.trmae(np.stack(outs[run:i]), np.stack(refs[run:i])))
                run = i
        start += n
    if "trmae" in which:
        res["trmae"] = float(np.mean(trm)) if trm else None
    if "wte" in which:
        res["wte"] = _wte(outs, refs, seq_lengths, frames) if frames is not None else None
    res["frames"] = len(outs)
    return res


def _wte(outs, refs, seq_lengths, frames) -> float | None:
    """:func:`training.metrics.warped_temporal_error` pooled over sequences (sums of errors)."""
    num = den = 0.0
    start = 0
    for n in seq_lengths:
        p, r = metrics.warped_error_sums(outs[start:start + n], refs[start:start + n], frames[start:start + n])
        num, den, start = num + p, den + r, start + n
    return None if den == 0 else num / den


def run_methods(methods, seqs: list[list[Frame]], spp: int, log=print, warmup: int = 0) -> dict:
    """Run ``methods`` (method objects, see :mod:`training.methods`) over ``seqs`` at ``spp``;
    returns {method name: scores} (see :func:`score`).  Each sequence starts with a reset.

    With ``warmup`` > 0 each method's scores gain ``"after_warmup"``: the same metrics over the
    frames after the first ``warmup`` of every sequence, where a real-time user sees a history
    in full swing (None when no sequence is longer than that)."""
    outs: dict[str, list] = {m.name: [] for m in methods}
    refs, lengths, inputs = [], [], []
    for frames in seqs:
        for m in methods:
            m.reset()
        for fr in frames:
            fr_n = at_spp(fr, spp)
            refs.append(fr_n.reference)
            inputs.append(replace(fr_n, samples=None))   # motion and guides for "wte", no samples
            for m in methods:
                outs[m.name].append(m(fr_n))
        lengths.append(len(frames))
    res = {name: score(o, refs, lengths, frames=inputs) for name, o in outs.items()}
    if warmup:
        keep = [i for i, t in enumerate(t for n in lengths for t in range(n)) if t >= warmup]
        later = [max(0, n - warmup) for n in lengths]
        for name, o in outs.items():
            res[name]["after_warmup"] = score([o[i] for i in keep], [refs[i] for i in keep], later,
                                              frames=[inputs[i] for i in keep]) if keep else None
    return res


def pareto_front(points: dict[str, tuple[float, float]]) -> list[str]:
    """Names of the points ``{name: (ms, psnr)}`` no other point beats: none is at most as
    slow and at least as good with one of the two strictly better.  Ordered by time (then by
    PSNR); equal points are all kept."""
    front = []
    for n, (t, q) in points.items():
        dominated = any(t2 <= t and q2 >= q and (t2 < t or q2 > q)
                        for n2, (t2, q2) in points.items() if n2 != n)
        if not dominated:
            front.append(n)
    return sorted(front, key=lambda n: (points[n][0], points[n][1]))
