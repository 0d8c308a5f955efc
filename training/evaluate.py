"""``mcdenoise evaluate METHOD... --data DIR``: quality on held-out sequences.

Every method (an ONNX model file, ``noisy``, ``oidn-high``, ``oidn-fast``, ``svgf``: see
:mod:`runtime.methods`) is run frame by frame over every sequence (temporal state included,
reset between sequences), at ``--spp`` samples per pixel taken from the stored per-sample data
(the first n samples; pixel layers recomputed with :func:`runtime.frames.pixel_means`).  With
``stills=True`` only each sequence's first frame is scored, after a reset (no history).

Metrics from :mod:`runtime.metrics`: PSNR (ANF Eq. 14, over all frames), SSIM and FLIP, SMAPE,
relMSE over all frames, and TRMAE (mean over sequences of 2+ frames).  torch is not needed.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from runtime import metrics
from runtime.args import add_data, add_threads
from runtime.frames import Frame, FrameError, frame_paths, pixel_means, read_frame
from runtime.methods import check_distinct, load_method

#: Metric columns, in table order (TRMAE is per sequence, the others over all frames).
METRICS = ("psnr", "ssim", "flip", "smape", "relmse", "trmae")


def sequences(root: str) -> list[list[str]]:
    """Frame paths per sequence folder under ``root`` (or ``root`` itself if it holds frames)."""
    rootp = Path(root)
    if not rootp.is_dir():
        raise FrameError(f"{root}: dataset folder does not exist")
    if frame_paths(root):
        return [frame_paths(root)]
    seqs = [frame_paths(p) for p in sorted(rootp.iterdir()) if p.is_dir() and frame_paths(p)]
    if not seqs:
        raise FrameError(f"{root}: no sequences of frame_*.exr")
    return seqs


def at_spp(frame: Frame, n: int) -> Frame:
    """The frame as if rendered with its first ``n`` stored samples per pixel."""
    if frame.samples is None:
        raise FrameError(f"{frame.path}: no per-sample layers, cannot evaluate at {n} spp")
    if n > frame.spp:
        raise FrameError(f"{frame.path}: holds {frame.spp} samples per pixel, {n} requested")
    px = pixel_means(frame.samples[:n])
    return Frame(color=px["color"], albedo=px["albedo"], normal=px["normal"], depth=px["depth"],
                 position=px["position"], motion=frame.motion, valid=frame.valid,
                 reference=frame.reference, meta=dict(frame.meta, spp=n), path=frame.path)


def read_sequences(data: str, stills: bool = False) -> list[list[Frame]]:
    """Frames (with per-sample layers and a reference) of every sequence under ``data``; only
    the first frame of each with ``stills``."""
    out = []
    for paths in sequences(data):
        frames = [read_frame(p) for p in (paths[:1] if stills else paths)]
        for f in frames:
            if f.reference is None:
                raise FrameError(f"{f.path}: no reference layer to score against")
        out.append(frames)
    return out


def stored_spp(seqs: list[list[Frame]]) -> int:
    """Samples per pixel every frame of ``seqs`` holds (the smallest)."""
    return min(f.spp for s in seqs for f in s)


def score(outs: list[np.ndarray], refs: list[np.ndarray], seq_lengths: list[int]) -> dict:
    """Metrics of frames ``outs`` against ``refs`` ((H, W, 3) linear radiance; flat lists,
    sequences back to back with lengths ``seq_lengths``): {psnr, ssim, flip, smape, relmse,
    trmae, frames}.

    Frames may differ in size (sequences of several sizes, a sequence that changes
    resolution); every metric then pools as it does over frames of one size: PSNR, SMAPE and
    relMSE over all pixels, SSIM over all valid window positions, FLIP over all pixels, TRMAE
    over the runs of equal-sized frames within each sequence (mean over runs)."""
    if len(outs) != len(refs) or sum(seq_lengths) != len(outs):
        raise ValueError(f"score: {len(outs)} outputs, {len(refs)} references, sequences of "
                         f"{sum(seq_lengths)} frames")
    outs = [np.asarray(x, np.float32) for x in outs]
    refs = [np.asarray(x, np.float32) for x in refs]
    for i, (a, b) in enumerate(zip(outs, refs)):
        if a.shape != b.shape:
            raise ValueError(f"score: frame {i} is {a.shape}, its reference {b.shape}")
    o, r = metrics.pixels(outs), metrics.pixels(refs)
    res = {"psnr": metrics.psnr(o, r), "smape": metrics.smape(o, r), "relmse": metrics.relmse(o, r)}
    # Windowed metrics per frame size, weighted by what each one averages over.
    by_size: dict[tuple, list[int]] = {}
    for i, x in enumerate(outs):
        by_size.setdefault(x.shape, []).append(i)
    parts = {"ssim": [], "flip": []}           # (value, how many it averages over)
    for (h, w, _), idx in by_size.items():
        so, sr = np.stack([outs[i] for i in idx]), np.stack([refs[i] for i in idx])
        win = (h - metrics.SSIM_WINDOW + 1) * (w - metrics.SSIM_WINDOW + 1)
        parts["ssim"].append((metrics.ssim(so, sr), len(idx) * win))
        parts["flip"].append((metrics.flip(so, sr), len(idx) * h * w))
    for k, vw in parts.items():
        res[k] = vw[0][0] if len(vw) == 1 else float(sum(v * n for v, n in vw) / sum(n for _, n in vw))
    trm, start = [], 0
    for n in seq_lengths:
        run = start
        for i in range(start, start + n + 1):
            if i == start + n or outs[i].shape != outs[run].shape:
                if i - run >= 2:
                    trm.append(metrics.trmae(np.stack(outs[run:i]), np.stack(refs[run:i])))
                run = i
        start += n
    res["trmae"] = float(np.mean(trm)) if trm else None
    res["frames"] = len(outs)
    return res


def run_methods(methods, seqs: list[list[Frame]], spp: int, log=print) -> dict:
    """Run ``methods`` (method objects, see :mod:`runtime.methods`) over ``seqs`` at ``spp``;
    returns {method name: scores} (see :func:`score`).  Each sequence starts with a reset."""
    outs: dict[str, list] = {m.name: [] for m in methods}
    refs, lengths = [], []
    for frames in seqs:
        for m in methods:
            m.reset()
        for fr in frames:
            fr_n = at_spp(fr, spp)
            refs.append(fr_n.reference)
            for m in methods:
                outs[m.name].append(m(fr_n))
        lengths.append(len(frames))
    return {name: score(o, refs, lengths) for name, o in outs.items()}


def default_methods(models: list[str], oidn: bool = True) -> list[str]:
    """``noisy``, then ``models`` (files or method names), then ``oidn-high`` (if ``oidn``)."""
    names = ["noisy"] + [m for m in models if m != "noisy"]
    if oidn and "oidn-high" not in names:
        names.append("oidn-high")
    return names


def evaluate(models: list[str], data: str, spp: int = 1, oidn: bool = True, threads: int = 0,
             stills: bool = False, log=print) -> dict:
    """{method: {psnr, ssim, flip, smape, relmse, trmae, frames}} over every sequence in
    ``data``, plus ``"_setup"``.  ``models``: ONNX files and/or method names; ``noisy`` and
    (with ``oidn``) ``oidn-high`` are always added."""
    sources = default_methods(models, oidn)
    methods = [load_method(n, threads=threads) for n in sources]
    check_distinct({n: m.name for n, m in zip(sources, methods)})
    seqs = read_sequences(data, stills)
    results = run_methods(methods, seqs, spp, log=log)
    results["_setup"] = {"data": str(data), "sequences": len(seqs), "spp": spp,
                         "stills": bool(stills)}
    log(format_results(results))
    return results


def _f(v, fmt):
    return "-" if v is None else format(v, fmt)


def format_results(results: dict) -> str:
    setup = results.get("_setup", {})
    n = next(iter(v["frames"] for k, v in results.items() if k != "_setup"))
    lines = [f"{setup.get('sequences')} sequences, {n} frames at {setup.get('spp')} spp from "
             f"{setup.get('data')}{' (first frames, no history)' if setup.get('stills') else ''}", "",
             "| method | PSNR dB | SSIM | FLIP | SMAPE | relMSE | TRMAE |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for k, v in results.items():
        if k == "_setup":
            continue
        lines.append(f"| {k} | {v['psnr']:.2f} | {_f(v.get('ssim'), '.4f')} | {_f(v.get('flip'), '.4f')} | "
                     f"{v['smape']:.4f} | {v['relmse']:.4f} | {_f(v['trmae'], '.4f')} |")
    return "\n".join(lines)


def add_arguments(p):
    p.add_argument("models", nargs="+",
                   help="ONNX model files and/or method names (noisy, oidn-high, oidn-fast, svgf)")
    add_data(p)
    p.add_argument("--spp", type=int, default=1, help="samples per pixel fed to the denoisers")
    p.add_argument("--stills", action="store_true",
                   help="score only each sequence's first frame, without history")
    p.add_argument("--no-oidn", action="store_true", help="do not add Open Image Denoise (quality high)")
    p.add_argument("--json", default=None, help="write the results as JSON here")
    add_threads(p)


def main(args) -> int:
    res = evaluate(args.models, args.data, args.spp, not args.no_oidn, args.threads, args.stills)
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    return 0
