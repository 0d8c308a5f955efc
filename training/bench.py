"""``mcdenoise bench``: quality, speed and compute of every method, in one run.

Methods (:mod:`runtime.methods`): every shipped model (the onnxruntime driver), Open Image
Denoise (``pyoidn``, colour + albedo + normal, quality high and fast), the SVGF-style classical
temporal filter (``svgf``, the non-neural baseline) and the noisy input.

*Quality* on test sets rendered from held-out seeds (training used ``--seed 1``):

* stills: each sequence's first frame, after a reset (no history), at 1, 2, 4, 8 spp, from
  :data:`STILLS` (``--seed 4``, 8 stored spp; rendered once with ``mcdenoise render`` when the
  folder is missing, reused afterwards);
* sequences: every frame with temporal state, at 1 and 4 spp, from :data:`SEQUENCES` (the
  README's ``data/test``, ``--seed 2``).  Sequence scores: PSNR over all frames, TRMAE per
  sequence (mean), SSIM, FLIP, SMAPE, relMSE (:mod:`training.evaluate`).

*Speed* in the same run, on a synthetic sequence with history (:func:`synthetic_frame`, fixed
seeds; timing hardly depends on the content: the one data-dependent branch, the reprojection
skipping bilinear taps of zero weight, never fires on its sub-pixel pan): per-stage median ms
of the onnxruntime driver (profiled: graph stages get their own rows) and of torch eager
(forward hooks), whole frame ms of OIDN and SVGF, at each ``--sizes``, all methods
interleaved frame by frame (:func:`time_interleaved`); the noisy input costs 0 ms.

*Compute*: FLOPs/FMAs and parameters of each model at each size (:mod:`runtime.flops`), the
achieved GFLOP/s (FLOPs / graph wall time) against this CPU's peak
(:func:`runtime.flops.cpu_peak`); Open Image Denoise's published U-Net counted from its layer
table (:data:`OIDN_UNET`).

Writes under ``--out``: ``bench.md`` (all tables, the charts linked), ``bench.csv`` (per-stage
timing), ``bench_quality.csv``, ``bench_flops.csv``, and the charts ``psnr_vs_time.png``
(PSNR of 1-spp sequences vs ms per frame at ``--chart-size``, log time axis, Pareto front),
``psnr_vs_spp.png`` and ``trmae.png``.  Every file states the command line that wrote it.
Quality numbers are deterministic given the data (and the data given its seeds); times are not.

``--quick`` (CI): 64x64, 3 timed frames, no torch, the tiny test set of ``--data`` (or a 2 x 3
frame set rendered at 64x64 with ``--seed 4``): a couple of minutes on 2 cores.
"""
from __future__ import annotations

import csv
import gc
import os
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from runtime import timing
from runtime.args import add_threads, parse_size

REPO = Path(__file__).resolve().parent.parent
DEFAULT_SIZES = ("256x256", "1280x720")
CHART_SIZE = "1280x720"
#: Built-in methods benchmarked beside the models, in table order.
BUILTIN_METHODS = ("noisy", "svgf", "oidn-fast", "oidn-high")
STILL_SPP = (1, 2, 4, 8)
SEQUENCE_SPP = (1, 4)


@dataclass(frozen=True)
class TestSet:
    """A test set and the ``mcdenoise render`` arguments that make it (all held-out seeds)."""

    folder: str
    scenes: int
    frames: int
    size: str
    spp: int
    ref_spp: int
    seed: int

    def render_args(self) -> list[str]:
        return ["render", "--out", self.folder, "--scenes", str(self.scenes), "--frames", str(self.frames),
                "--size", self.size, "--spp", str(self.spp), "--ref-spp", str(self.ref_spp),
                "--seed", str(self.seed)]


#: Still frames: 16 scenes, one frame each, 8 stored spp (seed 4: never trained or tested on).
STILLS = TestSet("data/bench-stills", 16, 1, "128x128", 8, 512, 4)
#: Sequences: the README's held-out test split (seed 2).
SEQUENCES = TestSet("data/test", 8, 4, "128x128", 4, 512, 2)
#: --quick without --data: a tiny set for both (seed 4).
QUICK = TestSet("data/bench-quick", 2, 3, "64x64", 8, 64, 4)

#: Open Image Denoise's U-Net as published in its training code (RenderKit/oidn
#: training/model.py, class UNet; the same layer sequence core/unet_filter.cpp builds): 3x3
#: convolutions as (name, input channels, output channels, resolution divisor); ``IC`` is the
#: input channel count (9: colour, albedo, normal).  2x2 max pools and nearest upsampling
#: between levels.  Images are padded to multiples of 16.
OIDN_UNET = (("enc_conv0", "IC", 32, 1), ("enc_conv1", 32, 32, 1), ("enc_conv2", 32, 48, 2),
             ("enc_conv3", 48, 64, 4), ("enc_conv4", 64, 80, 8), ("enc_conv5a", 80, 96, 16),
             ("enc_conv5b", 96, 96, 16), ("dec_conv4a", 96 + 64, 112, 8), ("dec_conv4b", 112, 112, 8),
             ("dec_conv3a", 112 + 48, 96, 4), ("dec_conv3b", 96, 96, 4), ("dec_conv2a", 96 + 32, 64, 2),
             ("dec_conv2b", 64, 64, 2), ("dec_conv1a", "64+IC", 64, 1), ("dec_conv1b", 64, 32, 1),
             ("dec_conv0", 32, 3, 1))


def oidn_unet_count(w: int, h: int, in_channels: int = 9) -> dict:
    """FMAs, FLOPs (2 per FMA + bias adds + ReLUs + pool compares, the rules of
    :mod:`runtime.flops`) and parameters of :data:`OIDN_UNET` on a ``w`` x ``h`` image."""
    pw, ph = -(-w // 16) * 16, -(-h // 16) * 16
    fmas = flops = params = 0
    for name, cin, cout, div in OIDN_UNET:
        cin = {"IC": in_channels, "64+IC": 64 + in_channels}.get(cin, cin)
        px = (pw // div) * (ph // div)
        f = px * cout * cin * 9
        fmas += f
        flops += 2 * f + px * cout * (1 if name == "dec_conv0" else 2)   # bias (+ ReLU)
        if name in ("enc_conv1", "enc_conv2", "enc_conv3", "enc_conv4"):
            flops += (px // 4) * cout * 4                                  # 2x2 max pool
        params += cout * cin * 9 + cout
    return {"fmas": fmas, "flops": flops, "params": params, "padded": f"{pw}x{ph}"}


# ------------------------------------------------------------------------------------------
# Timing
# ------------------------------------------------------------------------------------------

#: Camera pan of the synthetic timing sequence, pixels per frame: sub-pixel, so reprojection
#: blends all four bilinear taps as it does for a real camera (an integer pan would let the
#: driver skip three of them).
SYNTHETIC_PAN = (0.7, 0.3)


def synthetic_frame(w: int, h: int, t: int, seed: int = 0) -> dict:
    """A plausible frame: smooth albedo/normals, noisy colour, a slow sub-pixel pan
    (:data:`SYNTHETIC_PAN`) over a plane 5-6 units away whose world positions move with it,
    so the reprojection's consistency test passes as on a real surface."""
    rng = np.random.default_rng(seed + t)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    albedo = np.stack([0.5 + 0.3 * np.sin(xx / 17), 0.5 + 0.3 * np.cos(yy / 23), np.full_like(xx, 0.6)], -1)
    normal = np.stack([np.zeros_like(xx), np.zeros_like(xx), -np.ones_like(xx)], -1)
    depth = (5.0 + yy / h)[..., None]
    footprint = 5.0 / w   # world units per pixel at depth 5 and a ~53 degree field of view
    position = np.stack([(xx + SYNTHETIC_PAN[0] * t) * footprint, (yy + SYNTHETIC_PAN[1] * t) * footprint,
                         depth[..., 0]], -1)
    color = albedo * rng.exponential(1.0, (h, w, 3)).astype(np.float32)
    motion = np.empty((h, w, 2), np.float32)
    motion[..., 0], motion[..., 1] = SYNTHETIC_PAN
    return {"color": color.astype(np.float32), "albedo": albedo.astype(np.float32),
            "normal": normal, "depth": depth.astype(np.float32), "position": position.astype(np.float32),
            "motion": motion, "meta": {}}


def onnx_driver(path: str, threads: int, device: str = "cpu"):
    """The runtime driver of ``path`` set up for timing (graph profiled on the CPU).

    On ``device="cuda"`` (onnxruntime's CUDA provider) the graph is not profiled: CUDA kernels
    run asynchronously, so per-node times would be launch times; the graph row is the run()
    call, which returns only when the outputs are back on the host."""
    from runtime.denoiser import Denoiser
    from runtime.methods import PROVIDERS

    den = Denoiser.load(path, threads=threads, providers=PROVIDERS[device], profile=device == "cpu",
                        log=lambda m: None)
    if device == "cuda" and den.session.get_providers()[0] != "CUDAExecutionProvider":
        raise ValueError(f"{path}: onnxruntime has no CUDA provider here (providers: "
                           f"{', '.join(den.session.get_providers())}); install onnxruntime-gpu")
    return den


def builtin_method(name: str, threads: int, device: str = "cpu"):
    """A built-in method (:func:`runtime.methods.load_method`) for timing; None for ``noisy``."""
    from runtime.methods import load_method

    if name == "noisy":
        return None
    return oidn_cuda(name[len("oidn-"):]) if device == "cuda" and name.startswith("oidn-") else \
        load_method(name, threads=threads, device=device)


#: Pause before each timed call of :func:`time_interleaved`: onnxruntime's and Open Image
#: Denoise's worker threads spin for a while after a call, and would otherwise steal cores
#: from the next method.  (A longer pause also lets caches go cold and the vCPUs idle: with
#: 50 ms every method got slower, wskpn-3's numpy stages by about a quarter.)
SETTLE_S = 0.01


def time_interleaved(runners: dict, w: int, h: int, frames: int, warmup: int, seed: int = 0) -> dict:
    """Run every method of ``runners`` (name -> callable(frame)) on the synthetic sequence,
    interleaved frame by frame (frame t goes through every method before frame t + 1, the
    order rotating), so that a machine slowing down or speeding up mid-run affects every method
    alike and their ratios stay honest.  Returns name -> list of whole-call ms per frame
    (frames prepared outside the timed call)."""
    names = list(runners)
    ms: dict[str, list] = {n: [] for n in names}
    for t in range(warmup + frames):
        k = t % max(1, len(names))
        for n in names[k:] + names[:k]:
            fr = synthetic_frame(w, h, t, seed)
            time.sleep(SETTLE_S)
            t0 = time.perf_counter()
            runners[n](fr)
            ms[n].append(1e3 * (time.perf_counter() - t0))
    return ms


def oidn_cuda(quality: str):
    """Open Image Denoise on its CUDA device (pyoidn runs it on torch CUDA tensors); the copies
    to and from the GPU are part of the cost, as they are for the onnxruntime driver."""
    import torch

    from runtime.methods import OIDN

    class OIDNCuda(OIDN):
        def _array(self, a):
            return torch.from_numpy(a).cuda()

        def _numpy(self, out):
            return out.cpu().numpy().astype(np.float32, copy=False)

    return OIDNCuda(quality)


def bench_torch(model, contract_stages, w: int, h: int, frames: int, warmup: int, seed: int = 0,
                device: str = "cpu"):
    """{stage: median ms} and the graph's total of torch eager, stages by forward hooks (on
    ``device="cuda"`` each hook synchronises, so a stage's time is its kernels' time)."""
    import torch

    model = model.to(device)

    def now():
        if device == "cuda":
            torch.cuda.synchronize()
        return time.perf_counter()

    from runtime.frames import Frame
    from runtime.inputs import frame_inputs

    times: dict[str, list] = {}
    starts: dict[str, float] = {}
    handles = []
    for s in contract_stages:
        mod = getattr(model, s, None)
        if mod is None:
            continue
        handles.append(mod.register_forward_pre_hook(lambda m, a, s=s: starts.__setitem__(s, now())))
        handles.append(mod.register_forward_hook(
            lambda m, a, o, s=s: times.setdefault(s, []).append(1e3 * (now() - starts[s]))))
    def inputs(t):
        # A fresh frame per call, prepared outside the timed region, as the onnxruntime driver
        # gets one: timing one tensor set over and over would run torch from warm caches.
        frame = Frame(**synthetic_frame(w, h, t, seed))
        feeds = {k: torch.from_numpy(v).to(device) for k, v in frame_inputs(
            frame, [n for n in model.input_names if not n.startswith("prev_") and n != "history"]).items()}
        args = []
        for n in model.input_names:
            if n == "history":
                args.append(torch.ones(1, 1, h, w, device=device))
            elif n.startswith("prev_"):
                args.append(feeds["color"].clone())
            else:
                args.append(feeds[n])
        return args

    total = []
    with torch.inference_mode():
        for i in range(warmup + frames):
            args = inputs(i)
            t0 = now()
            model(*args)
            total.append(1e3 * (now() - t0))
    for hd in handles:
        hd.remove()
    med = {s: statistics.median(v[warmup:]) for s, v in times.items()}
    med[timing.GRAPH] = statistics.median(total[warmup:])
    return med


# ------------------------------------------------------------------------------------------
# Pareto front
# ------------------------------------------------------------------------------------------

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


# ------------------------------------------------------------------------------------------
# Data
# ------------------------------------------------------------------------------------------

def ensure_testset(ts: TestSet, log=print) -> tuple[str, float | None]:
    """The folder of ``ts``, rendered with ``mcdenoise render`` (in a subprocess) if it does
    not hold ``ts.scenes`` sequences yet; returns (folder, render seconds or None if reused)."""
    from training.evaluate import sequences

    folder = ts.folder if os.path.isabs(ts.folder) else str(REPO / ts.folder)
    try:
        if len(sequences(folder)) >= ts.scenes:
            return folder, None
    except Exception:
        pass
    args = ts.render_args()
    args[2] = folder
    log(f"rendering the test set: mcdenoise {' '.join(ts.render_args())}")
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "runtime.cli", *args], cwd=str(REPO),
                          capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"render failed (mcdenoise {' '.join(args)}):\n{proc.stderr[-3000:]}")
    return folder, time.perf_counter() - t0


# ------------------------------------------------------------------------------------------
# The run
# ------------------------------------------------------------------------------------------

def _model_paths(models) -> list[str]:
    from runtime.methods import shipped_models

    models = list(models) or shipped_models()
    if not models:
        raise ValueError("no models given and none shipped under models/")
    return [str(m) for m in models]


def run(models=(), builtins=BUILTIN_METHODS, sizes=DEFAULT_SIZES, chart_size=CHART_SIZE, frames=5,
        warmup=2, threads=0, torch_too=True, quality=True, stills=None, data=None, quick=False,
        seed=0, out="docs/results", command="mcdenoise bench", log=print, device="cpu") -> dict:
    """Run the benchmark and write every output file; returns the collected results.

    ``models``: ONNX files (default: the shipped ones).  ``builtins``: built-in methods.
    ``stills`` / ``data``: folders of the still and sequence test sets (default: render or reuse
    :data:`STILLS` / :data:`SEQUENCES`; with ``quick``, ``data`` serves both, else :data:`QUICK`).
    """
    from runtime.denoiser import Denoiser
    from runtime.methods import check_distinct

    t_start = time.perf_counter()
    models = _model_paths(models)
    sizes = [parse_size(s) if isinstance(s, str) else tuple(s) for s in sizes]
    chart = parse_size(chart_size) if isinstance(chart_size, str) else tuple(chart_size)
    if chart not in sizes:
        sizes.append(chart)
    threads_used = threads or len(os.sched_getaffinity(0))
    machine = timing.cpu_name() if device == "cpu" else f"{gpu_name()} (CUDA), host {timing.cpu_name()}"
    names = {p: Denoiser.load(p, log=lambda m: None).contract.spec_name for p in models}
    check_distinct({**{b: b for b in builtins}, **names})
    res = {"command": command, "device": machine, "compute_device": device, "threads": threads_used, "chart_size": chart,
           "sizes": sizes, "frames": frames, "warmup": warmup, "models": names,
           "builtins": list(builtins)}

    # --- quality
    if quality:
        res["quality"], res["testsets"] = quality_part(models, builtins, stills, data, quick, threads, log)
    # --- timing
    res["stage_rows"], res["frame_ms"] = timing_part(models, builtins, sizes, frames, warmup, threads,
                                                     torch_too, seed, log, device)
    # --- compute
    res["flops"] = flops_part(names, sizes, log, device)
    res["seconds"] = time.perf_counter() - t_start
    write_outputs(res, out)
    log(f"bench took {res['seconds']:.0f} s; wrote {out}/bench.md")
    return res


def quality_part(models, builtins, stills, data, quick, threads, log):
    from runtime.methods import load_method
    from training.evaluate import read_sequences, run_methods, stored_spp

    testsets = {}
    if quick:
        folder, secs = (data, None) if data else ensure_testset(QUICK, log)
        stills_dir = stills or folder
        seq_dir = folder
        testsets["render_s"] = secs
    else:
        if stills:
            stills_dir, s1 = stills, None
        else:
            stills_dir, s1 = ensure_testset(STILLS, log)
        if data:
            seq_dir, s2 = data, None
        else:
            seq_dir, s2 = ensure_testset(SEQUENCES, log)
        testsets["render_s"] = (s1 or 0) + (s2 or 0) if (s1 or s2) else None
    methods = [load_method(n, threads=threads) for n in ["noisy"] + [b for b in builtins if b != "noisy"]]
    methods += [load_method(p, threads=threads) for p in models]
    order = ["noisy"] + [m.name for m in methods if m.name != "noisy"]
    methods = sorted(methods, key=lambda m: order.index(m.name))
    qual = {}
    for kind, folder, spps in (("stills", stills_dir, STILL_SPP), ("sequences", seq_dir, SEQUENCE_SPP)):
        t0 = time.perf_counter()
        seqs = read_sequences(folder, stills=(kind == "stills"))
        have = stored_spp(seqs)
        use = [s for s in spps if s <= have]
        testsets[kind] = {"folder": _rel(folder), "sequences": len(seqs),
                          "frames": sum(len(s) for s in seqs), "size": "x".join(map(str, seqs[0][0].size[::-1])),
                          "stored_spp": have, "spp": use,
                          "ref_spp": seqs[0][0].meta.get("ref_spp"),
                          "scene_seeds": sorted({f.meta.get("scene_seed") for s in seqs for f in s} - {None})}
        for spp in use:
            qual[(kind, spp)] = run_methods(methods, seqs, spp, log=log)
            log(f"quality {kind} at {spp} spp: " + ", ".join(f"{k} {v['psnr']:.2f} dB"
                                                             for k, v in qual[(kind, spp)].items()))
        testsets[kind]["seconds"] = time.perf_counter() - t0
    return qual, testsets


def timing_part(models, builtins, sizes, frames, warmup, threads, torch_too, seed, log, device="cpu"):
    """Per-stage and whole-frame medians of every model and built-in method at every size:
    all methods timed interleaved (:func:`time_interleaved`), then torch eager per model."""
    from training.specs import build_model, parse_spec

    if torch_too:
        import torch

        if threads:
            torch.set_num_threads(threads)
    rows, frame_ms = [], {}
    for w, h in sizes:
        size = f"{w}x{h}"
        dens = {path: onnx_driver(path, threads, device) for path in models}
        methods = {b: builtin_method(b, threads, device) for b in builtins}
        runners = {**{("model", p): d for p, d in dens.items()},
                   **{("method", b): m for b, m in methods.items() if m is not None}}
        ms = time_interleaved(runners, w, h, frames, warmup, seed)
        results = {path: (den.contract, timing.medians(den.stage_times()[warmup:])) for path, den in dens.items()}
        # torch eager alone, after the other methods' sessions and thread pools are released
        del dens, methods, runners
        gc.collect()
        for path, (c, ort_med) in results.items():
            stages = [s["name"] for s in c.stages]
            torch_med = {}
            if torch_too:
                spec = parse_spec(c.spec_toml, f"{path} (embedded spec)")
                model = build_model(spec).eval().deploy()
                torch_med = bench_torch(model, stages, w, h, frames, warmup, seed, device)
            order = (list(timing.DRIVER_STAGES_BEFORE) + stages + list(timing.DRIVER_STAGES_AFTER)
                     + [timing.GRAPH, timing.TOTAL])
            for s in order:
                rows.append({"model": c.spec_name, "size": size, "stage": s,
                             "onnxruntime_ms": ort_med.get(s), "torch_ms": torch_med.get(s),
                             "paper_ms": (c.paper or {}).get(timing.paper_key(s)) if timing.paper_key(s) else None})
            frame_ms[(c.spec_name, size)] = ort_med[timing.TOTAL]
            log(f"{c.spec_name} {size}: onnxruntime {ort_med[timing.TOTAL]:.1f} ms/frame"
                + (f", torch graph {torch_med[timing.GRAPH]:.1f} ms" if torch_med else ""))
        for b in builtins:
            m = statistics.median(ms[("method", b)][warmup:]) if ("method", b) in ms else 0.0
            frame_ms[(b, size)] = m
            rows.append({"model": b, "size": size, "stage": timing.TOTAL, "onnxruntime_ms": None,
                         "torch_ms": None, "paper_ms": None, "method_ms": m})
            log(f"{b} {size}: {m:.1f} ms/frame")
    return rows, frame_ms


def gpu_name() -> str:
    """The CUDA device's name (torch), for tables written with ``--device cuda``."""
    try:
        import torch

        return torch.cuda.get_device_name(0)
    except Exception:  # a label only: never fail a benchmark over it
        return "CUDA GPU"


def flops_part(names: dict, sizes, log, device="cpu"):
    """FLOP counts of every model (``names``: path -> spec name) at each size and 1280x720,
    Open Image Denoise's published U-Net, and this CPU's peak."""
    from runtime.flops import count_flops, cpu_peak

    peak = cpu_peak() if device == "cpu" else {"gflops": None, "assumptions": "GPU peak not stated"}
    out = {"peak": peak, "models": {}, "oidn": {}}
    all_sizes = sorted(set(sizes) | {(1280, 720)})
    for path, name in names.items():
        for w, h in all_sizes:
            out["models"][(name, f"{w}x{h}")] = count_flops(path, w, h)
        c = out["models"][(name, "1280x720")]
        log(f"{name}: {c.flops / 1e9:.2f} GFLOP ({c.fmas / 1e9:.2f} GFMA) per 1280x720 frame, "
            f"{c.params} parameters" + (f"; not counted: {c.uncounted}" if c.uncounted else ""))
    for w, h in all_sizes:
        out["oidn"][f"{w}x{h}"] = oidn_unet_count(w, h)
    return out


# ------------------------------------------------------------------------------------------
# Output
# ------------------------------------------------------------------------------------------

def _fmt(v, spec=".2f"):
    return "-" if v is None else format(v, spec)


def _method_order(res) -> list[str]:
    return ["noisy"] + [b for b in res["builtins"] if b != "noisy"] + list(res["models"].values())


def chart_points(res) -> dict[str, tuple[float, float]]:
    """{method: (ms per frame at the chart size, PSNR of 1-spp sequences)}."""
    size = "x".join(map(str, res["chart_size"]))
    q = res.get("quality", {}).get(("sequences", 1), {})
    pts = {}
    for m in _method_order(res):
        if m in q and (m, size) in res["frame_ms"]:
            pts[m] = (res["frame_ms"][(m, size)], q[m]["psnr"])
    return pts


def write_outputs(res, out) -> None:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_stage_csv(res, out / "bench.csv")
    write_flops_csv(res, out / "bench_flops.csv")
    if "quality" in res:
        write_quality_csv(res, out / "bench_quality.csv")
        write_charts(res, out)
    (out / "bench.md").write_text(markdown(res))


def _csv_header(fh, res):
    fh.write(f"# written by: {res['command']}\n")


def write_stage_csv(res, path):
    keys = ["model", "size", "stage", "onnxruntime_ms", "torch_ms", "paper_ms", "method_ms"]
    with open(path, "w", newline="") as fh:
        _csv_header(fh, res)
        wr = csv.DictWriter(fh, fieldnames=keys)
        wr.writeheader()
        for r in res["stage_rows"]:
            wr.writerow({k: r.get(k) for k in keys})


def write_quality_csv(res, path):
    size = "x".join(map(str, res["chart_size"]))
    keys = ["method", "set", "spp", "psnr", "ssim", "flip", "smape", "relmse", "trmae", "frames",
            "ms_per_frame", "timing_size"]
    with open(path, "w", newline="") as fh:
        _csv_header(fh, res)
        wr = csv.DictWriter(fh, fieldnames=keys)
        wr.writeheader()
        for (kind, spp), per in res["quality"].items():
            for m, v in per.items():
                wr.writerow({"method": m, "set": kind, "spp": spp, **{k: v.get(k) for k in keys[3:10]},
                             "ms_per_frame": res["frame_ms"].get((m, size)), "timing_size": size})


def write_flops_csv(res, path):
    keys = ["method", "size", "stage", "gflop", "gfma", "params", "graph_ms", "gflop_per_s"]
    times = {(r["model"], r["size"], r["stage"]): r.get("onnxruntime_ms") for r in res["stage_rows"]}
    with open(path, "w", newline="") as fh:
        _csv_header(fh, res)
        wr = csv.DictWriter(fh, fieldnames=keys)
        wr.writeheader()
        for (name, size), c in res["flops"]["models"].items():
            for st, v in list(c.per_stage.items()) + [(timing.GRAPH, {"flops": c.flops, "fmas": c.fmas})]:
                ms = times.get((name, size, st))
                wr.writerow({"method": name, "size": size, "stage": st, "gflop": v["flops"] / 1e9,
                             "gfma": v["fmas"] / 1e9, "params": c.params if st == timing.GRAPH else None,
                             "graph_ms": ms, "gflop_per_s": v["flops"] / 1e9 / (ms / 1e3) if ms else None})
        for size, c in res["flops"]["oidn"].items():
            for q in ("high",):   # quality fast: not counted (see bench.md)
                ms = res["frame_ms"].get((f"oidn-{q}", size))
                wr.writerow({"method": f"oidn-{q}", "size": size, "stage": timing.TOTAL, "gflop": c["flops"] / 1e9,
                             "gfma": c["fmas"] / 1e9, "params": c["params"], "graph_ms": ms,
                             "gflop_per_s": c["flops"] / 1e9 / (ms / 1e3) if ms else None})


def write_charts(res, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401  (matplotlib.ticker below)

    meta = {"Description": f"written by: {res['command']}", "Software": "mcdenoise bench"}
    size = "x".join(map(str, res["chart_size"]))
    ts = res["testsets"]
    foot = f"written by: {res['command']}"

    # PSNR vs time
    pts = chart_points(res)
    front = pareto_front(pts)
    fig, ax = plt.subplots(figsize=(8, 5.5))
    timed = {m: p for m, p in pts.items() if p[0] > 0}
    xmin = min((p[0] for p in timed.values()), default=1.0) / 1.6
    xmax = max((p[0] for p in timed.values()), default=10.0) * 1.6
    for i, (m, (t, q)) in enumerate(sorted(pts.items(), key=lambda kv: kv[1][0])):
        if t > 0:
            ax.scatter([t], [q], s=40, zorder=3, color="C3" if m in front else "C0")
            ax.annotate(m, (t, q), textcoords="offset points", xytext=(6, 5 if i % 2 else -13), fontsize=9)
        else:
            ax.axhline(q, color="grey", ls=":", lw=1)
            ax.annotate(f"{m} (0 ms)", (xmin, q), textcoords="offset points", xytext=(4, 4),
                        fontsize=9, color="grey")
    fx = [max(pts[m][0], xmin) for m in front] + [xmax]
    fy = [pts[m][1] for m in front]
    if fy:
        ax.step(fx, fy + [fy[-1]], where="post", color="C3", lw=1.2, label="Pareto front")
        ax.legend(loc="lower right")
    ax.set_xscale("log")
    ax.set_xlim(xmin, xmax)
    ax.xaxis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xlabel(f"ms per frame at {size} (log scale)")
    ax.set_ylabel(f"PSNR dB, 1-spp sequences ({ts['sequences']['size']})")
    ax.set_title(f"Quality vs time: {size} on {res['device']}, {res['threads']} threads", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    fig.text(0.01, 0.005, foot, fontsize=6, color="grey")
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    fig.savefig(out / "psnr_vs_time.png", dpi=120, metadata=meta)
    plt.close(fig)

    # PSNR vs spp
    order = _method_order(res)
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.5), sharey=True)
    for ax, kind in zip(axes, ("stills", "sequences")):
        spps = ts[kind]["spp"]
        for i, m in enumerate(order):
            ys = [res["quality"][(kind, s)][m]["psnr"] for s in spps if m in res["quality"][(kind, s)]]
            if len(ys) == len(spps):
                ax.plot(spps, ys, marker="o", label=m, color=f"C{i}", ls=":" if m == "noisy" else "-")
        ax.set_xscale("log", base=2)
        ax.set_xticks(spps)
        ax.set_xticklabels([str(s) for s in spps])
        ax.set_xlabel("samples per pixel")
        ax.set_title(f"{kind}: {ts[kind]['frames']} frames at {ts[kind]['size']}"
                     + (" (first frames, no history)" if kind == "stills" else " (with history)"), fontsize=9)
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("PSNR dB (tonemapped, ANF Eq. 14)")
    axes[1].legend(fontsize=8, loc="lower right")
    fig.text(0.01, 0.005, foot, fontsize=6, color="grey")
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.savefig(out / "psnr_vs_spp.png", dpi=120, metadata=meta)
    plt.close(fig)

    # TRMAE
    spps = ts["sequences"]["spp"]
    fig, ax = plt.subplots(figsize=(8, 4.5))
    width = 0.8 / max(1, len(spps))
    for j, s in enumerate(spps):
        vals = [res["quality"][("sequences", s)].get(m, {}).get("trmae") or 0.0 for m in order]
        ax.bar(np.arange(len(order)) + (j - (len(spps) - 1) / 2) * width, vals, width, label=f"{s} spp")
    ax.set_xticks(np.arange(len(order)))
    ax.set_xticklabels(order, rotation=20)
    ax.set_ylabel("TRMAE (ANF Eq. 16, lower is steadier)")
    ax.set_title(f"Temporal stability on {ts['sequences']['sequences']} sequences at {ts['sequences']['size']}",
                 fontsize=10)
    ax.legend()
    ax.grid(True, axis="y", alpha=0.3)
    fig.text(0.01, 0.005, foot, fontsize=6, color="grey")
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.savefig(out / "trmae.png", dpi=120, metadata=meta)
    plt.close(fig)


def markdown(res) -> str:
    size = "x".join(map(str, res["chart_size"]))
    sizes = ["x".join(map(str, s)) for s in res["sizes"]]
    peak = res["flops"]["peak"]
    fsizes = sizes + ([] if "1280x720" in sizes else ["1280x720"])
    L = ["# mcdenoise bench", "",
         f"Written by `{res['command']}` in {res['seconds']:.0f} s. Machine: {res['device']}, "
         f"{res['threads']} threads. Times: median of {res['frames']} frames after {res['warmup']} "
         "warm-up frames of a synthetic sequence with history (a sub-pixel pan), every number "
         "from this one run; the methods run interleaved frame by frame, so machine drift hits "
         "all alike. "
         "onnxruntime and torch use the threads stated; Open Image Denoise runs its own thread pool "
         "(every core); SVGF is numpy.", ""]
    order = _method_order(res)
    if "quality" in res:
        ts = res["testsets"]
        q = res["quality"]
        pts = chart_points(res)
        front = set(pareto_front(pts))
        st, sq = ts["stills"], ts["sequences"]
        L += ["## Quality and speed", "",
              f"Stills: the first frame of each of {st['sequences']} sequences in `{st['folder']}` "
              f"({st['size']}, {st['stored_spp']} stored spp, reference {st['ref_spp']} spp, scene seeds "
              f"{_seeds(st['scene_seeds'])}), after a reset (no history). Sequences: {sq['sequences']} "
              f"sequences, {sq['frames']} frames in `{sq['folder']}` ({sq['size']}, reference {sq['ref_spp']} spp, "
              f"scene seeds {_seeds(sq['scene_seeds'])}), temporal state kept. Training used scene seeds "
              "100000+ (`--seed 1`). PSNR on ANF Eq. 14-tonemapped radiance over all frames; TRMAE "
              f"(ANF Eq. 16) mean over sequences. ms/frame: whole frame at {size} (models: the "
              "onnxruntime driver including reprojection).", "",
              f"| method | ms/frame {size} | " + " | ".join(f"stills {s} spp" for s in st["spp"]) + " | "
              + " | ".join(f"seq {s} spp" for s in sq["spp"]) + " | SSIM seq 1 | FLIP seq 1 | "
              + " | ".join(f"TRMAE {s} spp" for s in sq["spp"]) + " | Pareto |",
              "|---|" + "---:|" * (1 + len(st["spp"]) + len(sq["spp"]) + 2 + len(sq["spp"])) + "---|"]
        for m in order:
            ms = res["frame_ms"].get((m, size))
            cells = [_fmt(ms, ".1f")]
            cells += [_fmt(q[("stills", s)].get(m, {}).get("psnr")) for s in st["spp"]]
            cells += [_fmt(q[("sequences", s)].get(m, {}).get("psnr")) for s in sq["spp"]]
            s1 = q.get(("sequences", 1), {}).get(m, {})
            cells += [_fmt(s1.get("ssim"), ".4f"), _fmt(s1.get("flip"), ".4f")]
            cells += [_fmt(q[("sequences", s)].get(m, {}).get("trmae"), ".4f") for s in sq["spp"]]
            cells.append("yes" if m in front else "")
            L.append(f"| {m} | " + " | ".join(cells) + " |")
        L += ["", "Pareto front (fastest first): " + " → ".join(pareto_front(pts)) + f" (PSNR of 1-spp "
              f"sequences against ms per frame at {size}; the noisy input costs 0 ms).", "",
              "![PSNR vs time](psnr_vs_time.png)", "", "![PSNR vs spp](psnr_vs_spp.png)", "",
              "![TRMAE](trmae.png)", ""]
        rs = ts.get("render_s")
        L += [f"Quality part: stills {st['seconds']:.0f} s, sequences {sq['seconds']:.0f} s"
              + (f", test-set rendering {rs:.0f} s (once; reused afterwards)" if rs else
                 " (test sets reused, not rendered in this run)") + ".", ""]
        L += ["### All metrics", ""]
        for (kind, spp), per in q.items():
            L += [f"{kind}, {spp} spp:", "", "| method | PSNR dB | SSIM | FLIP | SMAPE | relMSE | TRMAE |",
                  "|---|---:|---:|---:|---:|---:|---:|"]
            for m in order:
                if m in per:
                    v = per[m]
                    L.append(f"| {m} | {v['psnr']:.2f} | {_fmt(v['ssim'], '.4f')} | {_fmt(v['flip'], '.4f')} | "
                             f"{v['smape']:.4f} | {v['relmse']:.4f} | {_fmt(v['trmae'], '.4f')} |")
            L.append("")

    # compute
    L += ["## Compute: FLOPs, parameters, achieved throughput", "",
          f"Counting rules: `runtime/flops.py` (ONNX shape inference at the frame size; Conv FMAs = "
          "N·Cout·Hout·Wout·Cin/groups·kh·kw, 1 FMA = 2 FLOPs, elementwise ops 1 FLOP per output "
          "element, pooling window size per output, reductions 1 per input element; data movement 0). "
          f"Achieved GFLOP/s = FLOPs / onnxruntime graph wall time of this run. CPU peak "
          f"{_fmt(peak['gflops'], '.1f')} GFLOP/s: {peak['assumptions']}.", "",
          "| method | params | " + " | ".join(f"GFLOP {s}" for s in fsizes) + " | "
          + " | ".join(f"GFLOP/s {s}" for s in sizes) + " | % of peak (largest size) |",
          "|---|---:|" + "---:|" * (len(fsizes) + len(sizes)) + "---:|"]
    times = {(r["model"], r["size"], r["stage"]): r.get("onnxruntime_ms") for r in res["stage_rows"]}
    for path, name in res["models"].items():
        cs = {s: res["flops"]["models"][(name, s)] for s in fsizes}
        rates = []
        for s in sizes:
            ms = times.get((name, s, timing.GRAPH))
            rates.append(cs[s].flops / 1e9 / (ms / 1e3) if ms else None)
        pct = (100 * rates[-1] / peak["gflops"]) if rates[-1] and peak["gflops"] else None
        L.append(f"| {name} | {cs[sizes[0]].params:,} | " + " | ".join(f"{cs[s].flops / 1e9:.3f}" for s in fsizes)
                 + " | " + " | ".join(_fmt(r, ".1f") for r in rates) + f" | {_fmt(pct, '.0f')} |")
    oc = res["flops"]["oidn"]
    if "oidn-high" in res["builtins"]:
        rates = []
        for s in sizes:
            ms = res["frame_ms"].get(("oidn-high", s))
            rates.append(oc[s]["flops"] / 1e9 / (ms / 1e3) if ms else None)
        pct = (100 * rates[-1] / peak["gflops"]) if rates[-1] and peak["gflops"] else None
        L.append(f"| oidn-high | {oc[sizes[0]]['params']:,} | "
                 + " | ".join(f"{oc[s]['flops'] / 1e9:.3f}" for s in fsizes) + " | "
                 + " | ".join(_fmt(r, ".1f") for r in rates) + f" | {_fmt(pct, '.0f')} |")
    if "oidn-fast" in res["builtins"]:
        L.append("| oidn-fast | not counted | " + " | ".join("not counted" for s in fsizes) + " | "
                 + " | ".join("-" for s in sizes) + " | - |")
    L += ["", "Open Image Denoise, quality high: the U-Net of its published training code "
          "(RenderKit/oidn `training/model.py`, the layer sequence `core/unet_filter.cpp` builds: 16 "
          "3x3 convolutions, 32-112 channels, 4 pooling levels; 9 input channels for colour + albedo + "
          "normal), on the image padded to multiples of 16; its ms is the whole `pyoidn.denoise` call "
          "(input/output conversion and autoexposure included), so its GFLOP/s is a lower bound. "
          "Quality fast: not counted; the published code we read does not say which network or "
          "precision pyoidn 2.5's `fast` runs" + _oidn_fast_note(res, sizes, oc, peak) + ". "
          "SVGF and the noisy input: not counted (no ONNX graph).", ""]
    # per-model tables beside the paper
    L += ["## Per-stage time beside each paper's table", "",
          "onnxruntime graph stages are profiler kernel sums, except for a model whose last stage the "
          "driver runs in bands of rows (wskpn; `runtime/bands.py`), whose graph stages are wall clock "
          "at sizes large enough for bands; driver stages (preprocess, reproject, "
          "postprocess, state update) wall clock; 'graph (wall)' is the run() call, beside the papers' "
          "totals (network only). Paper numbers are on the paper's GPU.", ""]
    stage_rows = res["stage_rows"]
    for path, name in res["models"].items():
        rows = [r for r in stage_rows if r["model"] == name]
        if not rows:
            continue
        stages = list(dict.fromkeys(r["stage"] for r in rows))
        paper = _paper(path)
        c720 = res["flops"]["models"].get((name, "1280x720"))
        L += [f"### {name} — {paper.get('table', '?')} ({paper.get('method', '?')}), paper: "
              f"{paper.get('device', '?')} at {paper.get('resolution', '?')}", "",
              "| stage | " + " | ".join(f"onnxruntime {s}" for s in sizes) + " | "
              + " | ".join(f"torch {s}" for s in sizes) + " | GFLOP 1280x720 | paper ms |",
              "|---|" + "---:|" * (2 * len(sizes) + 2)]
        for s in stages:
            by = {r["size"]: r for r in rows if r["stage"] == s}
            gf = None
            if c720 is not None:
                if s in c720.per_stage:
                    gf = c720.per_stage[s]["flops"] / 1e9
                elif s == timing.GRAPH:
                    gf = c720.flops / 1e9
            pk = timing.paper_key(s)
            p = paper.get(pk) if pk else None
            L.append(f"| {s} | " + " | ".join(_fmt(by.get(z, {}).get("onnxruntime_ms")) for z in sizes) + " | "
                     + " | ".join(_fmt(by.get(z, {}).get("torch_ms")) for z in sizes) + f" | {_fmt(gf, '.3f')} | "
                     f"{_fmt(p) if isinstance(p, (int, float)) else '-'} |")
        L.append("")
    L += ["## Whole frame, every method", "", "| method | " + " | ".join(sizes) + " |",
          "|---|" + "---:|" * len(sizes)]
    for m in order:
        L.append(f"| {m} | " + " | ".join(_fmt(res["frame_ms"].get((m, s)), ".1f") for s in sizes) + " |")
    ratios = []
    for s in sizes:
        o = res["frame_ms"].get(("oidn-high", s))
        for name in res["models"].values():
            ms = res["frame_ms"].get((name, s))
            if o and ms:
                ratios.append(f"- {name} at {s}: {ms:.1f} ms = {ms / o:.2f}x Open Image Denoise high ({o:.1f} ms)")
    if ratios:
        L += ["", "Against Open Image Denoise (quality high, same run):", ""] + ratios
    return "\n".join(L) + "\n"


def _oidn_fast_note(res, sizes, oc, peak) -> str:
    """Whether this run's oidn-fast time rules out the high-quality U-Net in fp32."""
    ms = res["frame_ms"].get(("oidn-fast", sizes[-1]))
    if not ms or not peak["gflops"]:
        return ""
    rate = oc[sizes[-1]]["flops"] / 1e9 / (ms / 1e3)
    if rate > peak["gflops"]:
        return (f", and its time here ({ms:.0f} ms at {sizes[-1]}) would mean {rate:.0f} GFLOP/s for "
                f"that U-Net, above the fp32 peak: a smaller network or a lower precision")
    return ""


def _rel(path) -> str:
    """``path`` relative to the repository when inside it (for the written files)."""
    p = Path(path).resolve()
    try:
        return str(p.relative_to(REPO))
    except ValueError:
        return str(path)


def _seeds(seeds) -> str:
    if not seeds:
        return "?"
    return f"{seeds[0]}-{seeds[-1]}" if len(seeds) > 1 else str(seeds[0])


def _paper(path) -> dict:
    from runtime.denoiser import Denoiser

    return Denoiser.load(path, log=lambda m: None).contract.paper or {}


# ------------------------------------------------------------------------------------------
# Command line
# ------------------------------------------------------------------------------------------

def add_arguments(p):
    p.add_argument("models", nargs="*", default=[],
                   help="ONNX files (default: every models/*.onnx shipped in the repository)")
    p.add_argument("--methods", nargs="*", default=list(BUILTIN_METHODS),
                   help=f"built-in methods besides the models (default: {' '.join(BUILTIN_METHODS)})")
    p.add_argument("--quick", action="store_true",
                   help="CI mode: 64x64, 3 timed frames, no torch, a tiny test set (--data or rendered)")
    p.add_argument("--sizes", nargs="+", default=None,
                   help=f"timing resolutions WxH (default {' '.join(DEFAULT_SIZES)}; --quick: 64x64)")
    p.add_argument("--chart-size", default=None,
                   help=f"resolution of the ms/frame in the chart and table (default {CHART_SIZE}; --quick: 64x64)")
    p.add_argument("--frames", type=int, default=None, help="timed frames per measurement (default 5; --quick 3)")
    p.add_argument("--warmup", type=int, default=None, help="untimed frames first (default 2; --quick 1)")
    p.add_argument("--data", default=None, metavar="DIR",
                   help=f"sequence test set (default {SEQUENCES.folder}, rendered if missing); with --quick "
                        "also the stills")
    p.add_argument("--stills", default=None, metavar="DIR",
                   help=f"still-frame test set (default {STILLS.folder}, rendered if missing)")
    p.add_argument("--seed", type=int, default=0, help="seed of the synthetic timing frames (default 0)")
    p.add_argument("--no-torch", action="store_true", help="skip torch eager timings")
    p.add_argument("--no-oidn", action="store_true", help="skip Open Image Denoise")
    p.add_argument("--no-quality", action="store_true", help="timing and FLOPs only")
    p.add_argument("--out", default=None,
                   help="output folder (default docs/results; --quick: runs/bench-quick)")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="cuda: onnxruntime's CUDA provider (needs onnxruntime-gpu), torch and Open Image "
                        "Denoise on the GPU; implies --no-quality (quality does not depend on the device) "
                        "and leaves out svgf (numpy, CPU only) unless --methods names it")
    add_threads(p)


def command_line(args) -> str:
    """The canonical command line of ``args`` (what every output file records)."""
    parts = ["mcdenoise", "bench"] + [os.path.relpath(m) if os.path.isabs(m) else m for m in args.models]
    if args.quick:
        parts.append("--quick")
    if list(args.methods) != list(BUILTIN_METHODS):
        parts += ["--methods"] + list(args.methods)
    for flag, v in (("--sizes", args.sizes), ("--chart-size", args.chart_size), ("--frames", args.frames),
                    ("--warmup", args.warmup), ("--data", args.data), ("--stills", args.stills),
                    ("--out", args.out)):
        if v is not None:
            parts += [flag] + (list(v) if isinstance(v, list) else [str(v)])
    if args.seed:
        parts += ["--seed", str(args.seed)]
    if args.threads:
        parts += ["--threads", str(args.threads)]
    if args.device != "cpu":
        parts += ["--device", args.device]
    for flag in ("no_torch", "no_oidn", "no_quality"):
        if getattr(args, flag):
            parts.append("--" + flag.replace("_", "-"))
    return " ".join(parts)


def main(args) -> int:
    q = args.quick
    builtins = [m for m in args.methods if not (args.no_oidn and m.startswith("oidn-"))]
    cuda = args.device == "cuda"
    if cuda and list(args.methods) == list(BUILTIN_METHODS):
        builtins = [m for m in builtins if m != "svgf"]
    out = args.out or ("runs/bench-quick" if q else "docs/results/gpu" if cuda else "docs/results")
    run(models=args.models, builtins=builtins,
        sizes=args.sizes or (["64x64"] if q else list(DEFAULT_SIZES)),
        chart_size=args.chart_size or ("64x64" if q else CHART_SIZE),
        frames=args.frames or (3 if q else 5), warmup=args.warmup if args.warmup is not None else (1 if q else 2),
        threads=args.threads, torch_too=not (args.no_torch or q), quality=not (args.no_quality or cuda),
        stills=args.stills, data=args.data, quick=q, seed=args.seed, out=out, command=command_line(args),
        device=args.device)
    print(f"wrote {out}/bench.md, bench.csv, bench_quality.csv, bench_flops.csv and the charts")
    return 0
