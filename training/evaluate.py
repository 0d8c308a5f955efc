"""``mcdenoise evaluate MODEL.onnx... --data DIR``: quality on held-out sequences.

Every sequence is run frame by frame through the runtime driver (temporal state included),
at ``--spp`` samples per pixel taken from the stored per-sample data (the first n samples;
pixel layers recomputed with :func:`runtime.frames.pixel_means`).  Open Image Denoise
(``pyoidn``, colour + albedo + normal, HDR, quality high) and the noisy input are scored on
the same frames.  Metrics from :mod:`runtime.metrics`: PSNR (ANF Eq. 14, over all frames),
SMAPE, relMSE, and TRMAE over each sequence.  torch is not needed.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from runtime.args import add_data, add_threads
from runtime.denoiser import Denoiser
from runtime.frames import Frame, FrameError, frame_paths, pixel_means, read_frame
from runtime.metrics import psnr, relmse, smape, trmae


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


def _scores(outs, refs) -> dict:
    o = np.stack(outs)
    r = np.stack(refs)
    return {"psnr": psnr(o, r), "smape": smape(o, r), "relmse": relmse(o, r)}


def evaluate(models: list[str], data: str, spp: int = 1, oidn: bool = True, threads: int = 0,
             log=print) -> dict:
    """{method: {psnr, smape, relmse, trmae, frames}} over every sequence in ``data``."""
    seqs = sequences(data)
    dens = {m: Denoiser.load(m, threads=threads, log=lambda msg: None) for m in models}
    names = {m: dens[m].contract.spec_name for m in models}
    results: dict[str, dict] = {}
    per_method: dict[str, list] = {"noisy": []}
    for m in models:
        per_method[names[m]] = []
    if oidn:
        import pyoidn

        per_method["oidn-high"] = []
    refs_all: list = []
    trm: dict[str, list] = {k: [] for k in per_method}
    for paths in seqs:
        for d in dens.values():
            d.reset()
        seq_out: dict[str, list] = {k: [] for k in per_method}
        seq_ref = []
        for p in paths:
            fr = at_spp(read_frame(p), spp)
            if fr.reference is None:
                raise FrameError(f"{p}: no reference layer to score against")
            seq_ref.append(fr.reference)
            seq_out["noisy"].append(fr.color)
            for m, d in dens.items():
                seq_out[names[m]].append(d(fr))
            if oidn:
                seq_out["oidn-high"].append(pyoidn.denoise(
                    np.ascontiguousarray(fr.color), albedo=np.ascontiguousarray(fr.albedo),
                    normal=np.ascontiguousarray(fr.normal), hdr=True, quality="high"))
        for k in per_method:
            per_method[k] += seq_out[k]
            if len(paths) >= 2:
                trm[k].append(trmae(np.stack(seq_out[k]), np.stack(seq_ref)))
        refs_all += seq_ref
    for k, outs in per_method.items():
        results[k] = _scores(outs, refs_all)
        results[k]["trmae"] = float(np.mean(trm[k])) if trm[k] else None
        results[k]["frames"] = len(outs)
    results["_setup"] = {"data": str(data), "sequences": len(seqs), "spp": spp}
    log(format_results(results))
    return results


def format_results(results: dict) -> str:
    setup = results.get("_setup", {})
    lines = [f"{setup.get('sequences')} sequences, {next(iter(v['frames'] for k, v in results.items() if k != '_setup'))} "
             f"frames at {setup.get('spp')} spp from {setup.get('data')}", "",
             "| method | PSNR dB | SMAPE | relMSE | TRMAE |", "|---|---:|---:|---:|---:|"]
    for k, v in results.items():
        if k == "_setup":
            continue
        tr = "-" if v["trmae"] is None else f"{v['trmae']:.4f}"
        lines.append(f"| {k} | {v['psnr']:.2f} | {v['smape']:.4f} | {v['relmse']:.4f} | {tr} |")
    return "\n".join(lines)


def add_arguments(p):
    p.add_argument("models", nargs="+", help="ONNX model files")
    add_data(p)
    p.add_argument("--spp", type=int, default=1, help="samples per pixel fed to the denoisers")
    p.add_argument("--no-oidn", action="store_true", help="skip Open Image Denoise")
    p.add_argument("--json", default=None, help="write the results as JSON here")
    add_threads(p)


def main(args) -> int:
    res = evaluate(args.models, args.data, args.spp, not args.no_oidn, args.threads)
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    return 0
