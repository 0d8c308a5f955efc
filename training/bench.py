"""``mcdenoise bench``: per-stage time of torch eager vs onnxruntime, and Open Image Denoise.

For each model and resolution, in one process and one run (these machines are noisy, so
every number in a table comes from the same run):

* onnxruntime: the runtime driver (:class:`runtime.denoiser.Denoiser`) on a synthetic
  sequence with history, profiled, so graph stages and driver stages get their own rows;
* torch eager: the same model (inference form, ``deploy()``), stages timed with forward
  hooks on the stage submodules;
* Open Image Denoise (``pyoidn``, colour + albedo + normal, quality high), whole frame.

Timing does not depend on the weights (no data-dependent control flow), so a model can be
benchmarked from its spec alone; shipped ONNX files are used when given.  Medians over
``--frames`` frames after ``--warmup`` frames.  Writes markdown and CSV under ``--out``.
"""
from __future__ import annotations

import csv
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from runtime import timing
from runtime.args import add_threads, parse_size

DEFAULT_SIZES = ("256x256", "1280x720")


def synthetic_frame(w: int, h: int, t: int, seed: int = 0) -> dict:
    """A plausible frame: smooth albedo/normals, noisy colour, a slow pan (1 px/frame)."""
    rng = np.random.default_rng(seed + t)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    albedo = np.stack([0.5 + 0.3 * np.sin(xx / 17), 0.5 + 0.3 * np.cos(yy / 23), np.full_like(xx, 0.6)], -1)
    normal = np.stack([np.zeros_like(xx), np.zeros_like(xx), -np.ones_like(xx)], -1)
    depth = (5.0 + yy / h)[..., None]
    position = np.stack([xx + t, yy, depth[..., 0]], -1)
    color = albedo * rng.exponential(1.0, (h, w, 3)).astype(np.float32)
    motion = np.zeros((h, w, 2), np.float32)
    motion[..., 0] = 1.0
    return {"color": color.astype(np.float32), "albedo": albedo.astype(np.float32),
            "normal": normal, "depth": depth.astype(np.float32), "position": position.astype(np.float32),
            "motion": motion, "meta": {}}


def bench_onnx(path: str, w: int, h: int, frames: int, warmup: int, threads: int):
    from runtime.denoiser import Denoiser

    den = Denoiser.load(path, threads=threads, profile=True, log=lambda m: None)
    for t in range(warmup + frames):
        den(synthetic_frame(w, h, t))
    rows = den.stage_times()[warmup:]
    return den, timing.medians(rows)


def bench_torch(model, contract_stages, w: int, h: int, frames: int, warmup: int):
    import torch

    from runtime.inputs import frame_inputs
    from runtime.frames import Frame

    times: dict[str, list] = {}
    starts: dict[str, float] = {}
    handles = []
    for s in contract_stages:
        mod = getattr(model, s, None)
        if mod is None:
            continue
        handles.append(mod.register_forward_pre_hook(lambda m, a, s=s: starts.__setitem__(s, time.perf_counter())))
        handles.append(mod.register_forward_hook(
            lambda m, a, o, s=s: times.setdefault(s, []).append(1e3 * (time.perf_counter() - starts[s]))))
    fr = synthetic_frame(w, h, 0)
    frame = Frame(**{k: v for k, v in fr.items()})
    feeds = {k: torch.from_numpy(v) for k, v in frame_inputs(frame, [n for n in model.input_names
                                                                    if not n.startswith("prev_") and n != "history"]).items()}
    args = []
    for n in model.input_names:
        if n == "history":
            args.append(torch.ones(1, 1, h, w))
        elif n.startswith("prev_"):
            args.append(feeds["color"].clone())
        else:
            args.append(feeds[n])
    total = []
    with torch.inference_mode():
        for i in range(warmup + frames):
            t0 = time.perf_counter()
            model(*args)
            total.append(1e3 * (time.perf_counter() - t0))
    for hd in handles:
        hd.remove()
    med = {s: statistics.median(v[warmup:]) for s, v in times.items()}
    med[timing.GRAPH] = statistics.median(total[warmup:])
    return med


def bench_oidn(w: int, h: int, frames: int, warmup: int, quality: str = "high"):
    try:
        import pyoidn
    except ImportError:
        return None
    fr = synthetic_frame(w, h, 0)
    ts = []
    for i in range(warmup + frames):
        t0 = time.perf_counter()
        pyoidn.denoise(fr["color"], albedo=fr["albedo"], normal=fr["normal"], hdr=True, quality=quality)
        ts.append(1e3 * (time.perf_counter() - t0))
    return statistics.median(ts[warmup:])


def add_arguments(p):
    p.add_argument("models", nargs="*", default=[],
                   help="ONNX files (default: every models/*.onnx shipped in the repository)")
    p.add_argument("--sizes", nargs="+", default=list(DEFAULT_SIZES), help="resolutions WxH")
    p.add_argument("--frames", type=int, default=5, help="timed frames per measurement")
    p.add_argument("--warmup", type=int, default=2, help="untimed frames first")
    p.add_argument("--no-torch", action="store_true", help="skip torch eager timings")
    p.add_argument("--no-oidn", action="store_true", help="skip Open Image Denoise")
    p.add_argument("--out", default="docs/results", help="folder for bench.md / bench.csv")
    add_threads(p)


def run(models, sizes, frames=5, warmup=2, threads=0, torch_too=True, oidn=True, out="docs/results",
        log=print) -> list[dict]:
    from runtime.denoiser import Denoiser
    from training.specs import build_model, parse_spec

    rows = []
    device = timing.cpu_name()
    threads_used = threads or os.cpu_count()
    if torch_too:
        import torch

        if threads:
            torch.set_num_threads(threads)
    for size in sizes:
        w, h = parse_size(size) if isinstance(size, str) else size
        oidn_ms = {q: bench_oidn(w, h, frames, warmup, q) for q in ("high", "fast")} if oidn else {}
        for path in models:
            den, ort_med = bench_onnx(path, w, h, frames, warmup, threads)
            c = den.contract
            stages = [s["name"] for s in c.stages]
            torch_med = {}
            if torch_too:
                spec = parse_spec(c.spec_toml, f"{path} (embedded spec)")
                model = build_model(spec).eval().deploy()
                torch_med = bench_torch(model, stages, w, h, frames, warmup)
            order = list(timing.DRIVER_STAGES_BEFORE) + stages + list(timing.DRIVER_STAGES_AFTER) + [timing.GRAPH, timing.TOTAL]
            for s in order:
                rows.append({"model": c.spec_name, "size": f"{w}x{h}", "stage": s,
                             "onnxruntime_ms": ort_med.get(s), "torch_ms": torch_med.get(s),
                             "paper_ms": (c.paper or {}).get(timing.paper_key(s)) if timing.paper_key(s) else None})
            log(f"{c.spec_name} {w}x{h}: onnxruntime {ort_med[timing.TOTAL]:.1f} ms/frame"
                + (f", torch graph {torch_med[timing.GRAPH]:.1f} ms" if torch_med else ""))
        for q, ms in oidn_ms.items():
            if ms is not None:
                rows.append({"model": f"oidn-{q}", "size": f"{w}x{h}", "stage": timing.TOTAL,
                             "onnxruntime_ms": None, "torch_ms": None, "paper_ms": None, "oidn_ms": ms})
                log(f"Open Image Denoise ({q}) {w}x{h}: {ms:.1f} ms/frame")
    write_tables(rows, out, device, threads_used, frames, warmup)
    return rows


def _fmt(v):
    return "-" if v is None else f"{v:.2f}"


def write_tables(rows, out, device, threads, frames, warmup) -> None:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    keys = ["model", "size", "stage", "onnxruntime_ms", "torch_ms", "paper_ms", "oidn_ms"]
    with open(out / "bench.csv", "w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=keys)
        wr.writeheader()
        for r in rows:
            wr.writerow({k: r.get(k) for k in keys})
    lines = [f"# Per-stage timing (median ms per frame)", "",
             f"Machine: {device}, {threads} threads. Median of {frames} frames after {warmup} warm-up "
             f"frames, all numbers from one run of `{' '.join(['mcdenoise'] + sys.argv[1:]) if sys.argv[0].endswith('mcdenoise') else 'mcdenoise bench'}`. "
             "Paper numbers are the paper's GPU (RTX 2080 Ti at 1280x720); graph stages are "
             "onnxruntime profiler kernel sums, 'graph (wall)' is the run() call.",
             "", "| model | size | stage | onnxruntime | torch eager | paper (GPU) | OIDN |",
             "|---|---|---|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['model']} | {r['size']} | {r['stage']} | {_fmt(r.get('onnxruntime_ms'))} | "
                     f"{_fmt(r.get('torch_ms'))} | {_fmt(r.get('paper_ms'))} | {_fmt(r.get('oidn_ms'))} |")
    # Whole-frame ratio against OIDN high at each size.
    ratios = []
    for size in dict.fromkeys(r["size"] for r in rows):
        oidn = next((r["oidn_ms"] for r in rows if r["size"] == size and r["model"] == "oidn-high"), None)
        for r in rows:
            if r["size"] == size and r["stage"] == timing.TOTAL and r.get("onnxruntime_ms") and oidn:
                ratios.append(f"- {r['model']} at {size}: {r['onnxruntime_ms']:.1f} ms = "
                              f"{r['onnxruntime_ms'] / oidn:.2f}x Open Image Denoise high ({oidn:.1f} ms)")
    if ratios:
        lines += ["", "Whole frame against Open Image Denoise (quality high, same run):", ""] + ratios
    (out / "bench.md").write_text("\n".join(lines) + "\n")


def main(args) -> int:
    models = args.models or sorted(str(p) for p in (Path(__file__).resolve().parent.parent / "models").glob("*.onnx"))
    if not models:
        raise ValueError("no models given and none shipped under models/")
    run(models, args.sizes, args.frames, args.warmup, args.threads, not args.no_torch, not args.no_oidn, args.out)
    print(f"wrote {args.out}/bench.md and bench.csv")
    return 0
