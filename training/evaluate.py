"""``mcdenoise evaluate METHOD... --data DIR``: quality on held-out sequences.

Every method (an ONNX model file, ``noisy``, ``oidn-high``, ``oidn-fast``, ``svgf``: see
:mod:`training.methods`) is run frame by frame over every sequence (temporal state included,
reset between sequences), at ``--spp`` samples per pixel taken from the stored per-sample data
(the first n samples; pixel layers recomputed with :func:`runtime.frames.pixel_means`).  With
``stills=True`` only each sequence's first frame is scored, after a reset (no history).

Metrics from :mod:`training.metrics`: PSNR (ANF Eq. 14, over all frames), SSIM and FLIP, SMAPE,
relMSE over all frames, and TRMAE (mean over sequences of 2+ frames).  torch is not needed.
With ``no_history`` every ONNX model that keeps a history is also scored reset before each frame (rows
"<name> (no history)", :class:`training.methods.WithoutHistory`): what its history earns.
"""
from __future__ import annotations

import json
from pathlib import Path


from mcdenoise.runtime.args import add_data, add_threads
from mcdenoise.training.methods import check_distinct, load_method
from mcdenoise.training.scoring import run_methods
from mcdenoise.training.testsets import read_sequences


def default_methods(models: list[str], oidn: bool = True) -> list[str]:
    """``noisy``, then ``models`` (files or method names), then ``oidn-high`` (if ``oidn``)."""
    names = ["noisy"] + [m for m in models if m != "noisy"]
    if oidn and "oidn-high" not in names:
        names.append("oidn-high")
    return names


def evaluate(models: list[str], data: str, spp: int = 1, oidn: bool = True, threads: int = 0,
             stills: bool = False, log=print, warmup: int = 0, accumulate_alpha: float | None = None,
             history_spp: float | None = None, no_history: bool = False) -> dict:
    """{method: {psnr, ssim, flip, smape, relmse, trmae, wte, frames[, after_warmup]}} over every
    sequence in ``data``, plus ``"_setup"``.  ``models``: ONNX files and/or method names;
    ``noisy`` and (with ``oidn``) ``oidn-high`` are always added. ``warmup``: also score the
    frames after the first ``warmup`` of each sequence; ``accumulate_alpha`` / ``history_spp``:
    every model's accumulation weight instead of its file's (see ``Denoiser.load``);
    ``no_history``: also every ONNX model that keeps a history, reset before each frame."""
    from mcdenoise.training.methods import ONNXModel, WithoutHistory

    sources = default_methods(models, oidn)
    methods = [load_method(n, threads=threads, accumulate_alpha=accumulate_alpha, history_spp=history_spp)
               for n in sources]
    check_distinct({n: m.name for n, m in zip(sources, methods)})
    if no_history:
        methods += [WithoutHistory(load_method(n, threads=threads, accumulate_alpha=accumulate_alpha,
                                                  history_spp=history_spp)) for n, m in zip(sources, methods)
                    if isinstance(m, ONNXModel) and m.denoiser.protocol.temporal]
    seqs = read_sequences(data, stills)
    results = run_methods(methods, seqs, spp, log=log, warmup=warmup)
    results["_setup"] = {"data": str(data), "sequences": len(seqs), "spp": spp,
                         "stills": bool(stills), "warmup": warmup, "accumulate_alpha": accumulate_alpha,
                         "history_spp": history_spp}
    log(format_results(results))
    return results


def load_results(path, after_warmup: bool = True) -> dict:
    """{method: scores} of an ``evaluate --json`` file without its ``"_setup"`` and its
    "(no history)" rows; with ``after_warmup`` the scores after warm-up where the file has them.
    {} for a missing file (a result not made yet)."""
    path = Path(path)
    if not path.exists():
        return {}
    d = json.loads(path.read_text())
    d.pop("_setup", None)
    return {m: (r.get("after_warmup") if after_warmup else None) or r for m, r in d.items() if "(no history)" not in m}


def _f(v, fmt):
    return "-" if v is None else format(v, fmt)


def format_results(results: dict) -> str:
    setup = results.get("_setup", {})
    n = next(iter(v["frames"] for k, v in results.items() if k != "_setup"))
    lines = [f"{setup.get('sequences')} sequences, {n} frames at {setup.get('spp')} spp from "
             f"{setup.get('data')}{' (first frames, no history)' if setup.get('stills') else ''}", "",
             "| method | PSNR dB | SSIM | FLIP | SMAPE | relMSE | TRMAE | WTE | after warm-up: PSNR | TRMAE | WTE |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for k, v in results.items():
        if k == "_setup":
            continue
        a = v.get("after_warmup") or {}
        lines.append(f"| {k} | {v['psnr']:.2f} | {_f(v.get('ssim'), '.4f')} | {_f(v.get('flip'), '.4f')} | "
                     f"{v['smape']:.4f} | {v['relmse']:.4f} | {_f(v['trmae'], '.4f')} | {_f(v.get('wte'), '.3f')} | "
                     f"{_f(a.get('psnr'), '.2f')} | {_f(a.get('trmae'), '.4f')} | {_f(a.get('wte'), '.3f')} |")
    return "\n".join(lines)


def add_arguments(p):
    p.add_argument("models", nargs="+",
                   help="ONNX model files and/or method names (noisy, oidn-high, oidn-fast, oidn-high-aa, oidn-fast-aa, svgf)")
    add_data(p)
    p.add_argument("--spp", type=int, default=1, help="samples per pixel fed to the denoisers")
    p.add_argument("--stills", action="store_true",
                   help="score only each sequence's first frame, without history")
    p.add_argument("--no-oidn", action="store_true", help="do not add Open Image Denoise (quality high)")
    p.add_argument("--warmup", type=int, default=0,
                   help="also score the frames after the first N of each sequence (a history in full swing)")
    p.add_argument("--alpha", type=float, default=None,
                   help="every model's accumulation weight of the current frame, in (0, 1], instead of its file's")
    p.add_argument("--history-spp", type=float, default=None, metavar="K",
                   help="every model's accumulation weight spp / (spp + K) instead of its file's (0: the fixed weight)")
    p.add_argument("--no-history", action="store_true",
                   help="also score every model that keeps a history reset before each frame (rows '(no history)'): what its history earns")
    p.add_argument("--json", default=None, help="write the results as JSON here")
    add_threads(p)


def main(args) -> int:
    if args.warmup < 0:
        raise ValueError(f"--warmup must be >= 0, got {args.warmup}")
    res = evaluate(args.models, args.data, args.spp, not args.no_oidn, args.threads, args.stills,
                   warmup=args.warmup, accumulate_alpha=args.alpha, history_spp=args.history_spp,
                   no_history=args.no_history)
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    return 0
