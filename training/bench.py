"""``mcdenoise bench``: quality, speed and compute of every method, in one run.

Methods (:mod:`training.methods`): every shipped model (the onnxruntime driver), Open Image
Denoise (``pyoidn``, colour + albedo + normal, quality high and fast), the SVGF-style classical
temporal filter (``svgf``, the non-neural baseline) and the noisy input.

*Quality* on test sets rendered from held-out seeds (training used ``--seed 1``):

* stills: each sequence's first frame, after a reset (no history), at 1, 2, 4, 8 spp, from
  :data:`training.testsets.STILLS` (``--seed 4``, 8 stored spp; rendered once with ``mcdenoise render`` when the
  folder is missing, reused afterwards);
* sequences: every frame with temporal state, at 1 and 4 spp, from :data:`training.testsets.SEQUENCES` (the
  README's ``data/test``, ``--seed 2``).  Sequence scores: PSNR over all frames, TRMAE per
  sequence (mean), SSIM, FLIP, SMAPE, relMSE (:func:`training.scoring.score`).

*Speed* in the same run, on a synthetic sequence with history (:func:`training.harness.synthetic_frame`, fixed
seeds; timing hardly depends on the content: the one data-dependent branch, the reprojection
skipping bilinear taps of zero weight, never fires on its sub-pixel pan): per-stage median ms
of the onnxruntime driver (profiled: graph stages get their own rows) and of torch eager
(forward hooks), whole frame ms of OIDN and SVGF, at each ``--sizes``, all methods
interleaved frame by frame (:func:`training.harness.time_interleaved`); the noisy input costs 0 ms.
Per-sample models (ANF, NDLE) are timed again at 1, 2, 4 and 8 spp at the smallest size, alone
(:func:`spp_part`): their per-sample stages must grow linearly in S, the rest not at all.

*Compute*: FLOPs/FMAs and parameters of each model at each size (:mod:`training.flops`), the
achieved GFLOP/s (FLOPs / graph wall time) against this CPU's peak
(:func:`training.flops.cpu_peak`); Open Image Denoise's published U-Net counted from its layer
table (:data:`training.harness.OIDN_UNET`).

Writes under ``--out``: ``bench.md`` (all tables, the charts linked), ``bench.csv`` (per-stage
timing), ``bench_quality.csv``, ``bench_flops.csv``, and the charts ``psnr_vs_time.png``
(PSNR of 1-spp sequences vs ms per frame at ``--chart-size``, log time axis, Pareto front),
``psnr_vs_spp.png`` and ``trmae.png``.  Every file states the command line that wrote it.
Quality numbers are deterministic given the data (and the data given its seeds); times are not.
This module only orchestrates: test sets, harness, scoring and report are their own modules.

``--quick`` (CI): 64x64, 3 timed frames, no torch, the tiny test set of ``--data`` (or a 2 x 3
frame set rendered at 64x64 with ``--seed 4``): a couple of minutes on 2 cores.
"""
from __future__ import annotations

import gc
import os
import statistics
import time


from mcdenoise.runtime import timing
from mcdenoise.runtime.args import add_data, add_seed, add_threads, parse_size
from mcdenoise.training.harness import (bench_torch, builtin_method, gpu_name, oidn_unet_count, onnx_driver,
                                        time_interleaved)
from mcdenoise.training.report import rel_path, write_outputs
from mcdenoise.training.scoring import run_methods
from mcdenoise.training.testsets import (HELD_OUT, LONG_SEQUENCES, QUICK, SEQUENCES, STILLS, TestSet, ensure, read_sequences,
                                         reference_check, stored_spp)

DEFAULT_SIZES = ("256x256", "1280x720")
CHART_SIZE = "1280x720"
#: Built-in methods benchmarked beside the models, in table order.
BUILTIN_METHODS = ("noisy", "svgf", "oidn-fast", "oidn-high")
STILL_SPP = (1, 2, 4, 8)
SEQUENCE_SPP = (1, 4)
#: Long sequences (issue 15): spp, and frames of each sequence left out of "after warm-up"
#: (a history blended at alpha 0.2 has built up by then); --quick: the tiny set, 1 frame.
LONG_SPP = (1, 4)
LONG_WARMUP = 8





# ------------------------------------------------------------------------------------------
# The run
# ------------------------------------------------------------------------------------------

def _model_paths(models) -> list[str]:
    from mcdenoise.training.methods import shipped_models

    models = list(models) or shipped_models()
    if not models:
        raise ValueError("no models given and none shipped under models/")
    return [str(m) for m in models]


def run(models=(), builtins=BUILTIN_METHODS, sizes=DEFAULT_SIZES, chart_size=CHART_SIZE, frames=5,
        warmup=2, threads=0, torch_too=True, quality=True, stills=None, data=None, quick=False,
        seed=0, out="docs/results", command="mcdenoise bench", log=print, device="cpu", long=True,
        memory=True) -> dict:
    """Run the benchmark and write every output file; returns the collected results.

    ``models``: ONNX files (default: the shipped ones).  ``builtins``: built-in methods.
    ``stills`` / ``data``: folders of the still and sequence test sets (default: render or reuse
    :data:`STILLS` / :data:`SEQUENCES`; with ``quick``, ``data`` serves both, else :data:`QUICK`).
    """
    from mcdenoise.runtime.denoiser import Denoiser
    from mcdenoise.training.methods import check_distinct

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
        res["quality"], res["testsets"] = quality_part(models, builtins, stills, data, quick, threads, log, long)
    # --- timing
    res["stage_rows"], res["frame_ms"] = timing_part(models, builtins, sizes, frames, warmup, threads,
                                                     torch_too, seed, log, device)
    # --- per-sample models against S
    res["spp_scaling"] = spp_part(models, min(sizes, key=lambda s: s[0] * s[1]), frames, warmup, threads,
                                  seed, log, device)
    # --- memory (CPU: a fresh process per method)
    if memory and device == "cpu":
        res["memory"] = memory_part(models, builtins, max(sizes, key=lambda s: s[0] * s[1]), threads, log)
    # --- compute
    res["flops"] = flops_part(names, sizes, log, device)
    res["seconds"] = time.perf_counter() - t_start
    write_outputs(res, out)
    log(f"bench took {res['seconds']:.0f} s; wrote {out}/bench.md")
    return res


def quality_part(models, builtins, stills, data, quick, threads, log, long=True):
    from mcdenoise.training.methods import WithoutHistory, load_method

    def rendered(ts: TestSet, given: str | None) -> tuple[str, float | None]:
        if given:
            return given, None
        folder, info = ensure(ts, log=log)
        return folder, info["wall_seconds"]

    testsets = {}
    seq_dir, s1 = rendered(QUICK if quick else SEQUENCES, data)
    # --quick: the stills are the first frames of the same (tiny) set unless --stills says
    stills_dir, s2 = (stills or seq_dir, None) if quick else rendered(STILLS, stills)
    sets = [("stills", stills_dir, STILL_SPP, 0), ("sequences", seq_dir, SEQUENCE_SPP, 0)]
    rs = [s1, s2]
    if long:
        # --quick: the tiny set stands in, so the code path runs in CI
        long_sets = {"long-quick": QUICK} if quick else {
            **{f"long-{n}": ts for n, ts in LONG_SEQUENCES.items()}, **{f"heldout-{n}": ts for n, ts in HELD_OUT.items()}}
        for kind, ts in long_sets.items():
            folder, secs = rendered(ts, seq_dir if quick else None)
            sets.append((kind, folder, LONG_SPP, 1 if quick else LONG_WARMUP))
            rs.append(secs)
            if not quick:   # are the references clean enough for the PSNR they measure?
                testsets[f"{kind}:reference_db"] = reference_check(ts, folder, log)["min_db"]
    testsets["render_s"] = sum(r or 0 for r in rs) if any(rs) else None
    methods = [load_method(n, threads=threads) for n in ["noisy"] + [b for b in builtins if b != "noisy"]]
    methods += [load_method(p, threads=threads) for p in models]
    order = ["noisy"] + [m.name for m in methods if m.name != "noisy"]
    methods = sorted(methods, key=lambda m: order.index(m.name))
    qual = {}
    # The long sets also score each model reset before every frame: what its history earns.
    bare = [WithoutHistory(load_method(p, threads=threads)) for p in models]
    for kind, folder, spps, warmup in sets:
        t0 = time.perf_counter()
        seqs = read_sequences(folder, stills=(kind == "stills"))
        have = stored_spp(seqs)
        use = [s for s in spps if s <= have]
        testsets[kind] = {"folder": rel_path(folder), "sequences": len(seqs),
                          "frames": sum(len(s) for s in seqs), "size": "x".join(map(str, seqs[0][0].size[::-1])),
                          "stored_spp": have, "spp": use,
                          "ref_spp": seqs[0][0].meta.get("ref_spp"),
                          "scene_seeds": sorted({f.meta.get("scene_seed") for s in seqs for f in s} - {None}),
                          "warmup": warmup}
        for spp in use:
            qual[(kind, spp)] = run_methods(methods + (bare if warmup else []), seqs, spp, log=log, warmup=warmup)
            log(f"quality {kind} at {spp} spp: " + ", ".join(f"{k} {v['psnr']:.2f} dB"
                                                             for k, v in qual[(kind, spp)].items()))
        testsets[kind]["seconds"] = time.perf_counter() - t0
    return qual, testsets


#: Samples per pixel of the timing frames when a per-sample model is timed (ANF Table 1: 4 spp).
TIMING_SPP = 4
#: Frames each method denoises for its peak memory (the history is in use from the second on).
MEMORY_FRAMES = 3


def timing_part(models, builtins, sizes, frames, warmup, threads, torch_too, seed, log, device="cpu"):
    """Per-stage and whole-frame medians of every model and built-in method at every size:
    all methods timed interleaved (:func:`time_interleaved`), then torch eager per model."""
    from mcdenoise.training.specs import build_model, parse_spec

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
        # Per-sample models (ANF) read samples: the timing frames carry TIMING_SPP of them, as
        # the paper's Table 1 does (4 spp), and every method gets the same frames.
        spp = TIMING_SPP if any(d.contract.samples_input for d in dens.values()) else 0
        ms = time_interleaved(runners, w, h, frames, warmup, seed, spp)
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
                torch_med = bench_torch(model, spec.protocol, stages, w, h, frames, warmup, seed, device, TIMING_SPP)
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


#: Samples per pixel of the per-sample models' scaling rows (issue 16: the per-sample stages
#: grow linearly in S, everything after the average over samples does not depend on it).
SCALING_SPP = (1, 2, 4, 8)


def spp_part(models, size, frames, warmup, threads, seed, log, device="cpu") -> dict:
    """Per-stage medians (ms) of every per-sample model at each S of :data:`SCALING_SPP`, on
    the same synthetic frames at ``size`` (W, H), a fresh driver per S.  Returns
    ``{"size": "WxH", "spp": [...], "models": {name: {stage: [ms at each S]}}}``; no models
    when none reads samples."""
    from mcdenoise.runtime.denoiser import Denoiser

    w, h = size
    out = {"size": f"{w}x{h}", "spp": list(SCALING_SPP), "models": {}}
    for path in models:
        if not Denoiser.load(path, log=lambda m: None).contract.samples_input:
            continue
        per_spp = []
        for spp in SCALING_SPP:
            den = onnx_driver(path, threads, device)
            time_interleaved({path: den}, w, h, frames, warmup, seed, spp)
            per_spp.append(timing.medians(den.stage_times()[warmup:]))
            name = den.contract.spec_name
            stages = ([s for s in timing.DRIVER_STAGES_BEFORE] + [s["name"] for s in den.contract.stages]
                      + list(timing.DRIVER_STAGES_AFTER) + [timing.GRAPH, timing.TOTAL])
            del den
            gc.collect()
        out["models"][name] = {s: [m.get(s) for m in per_spp] for s in stages if any(s in m for m in per_spp)}
        log(f"{name} {w}x{h} at {', '.join(map(str, SCALING_SPP))} spp: "
            + ", ".join(f"{m[timing.TOTAL]:.1f}" for m in per_spp) + " ms/frame")
    return out


def memory_part(models, builtins, size, threads, log) -> dict:
    """Peak resident memory of every method on the same synthetic frames at ``size``, each in a
    fresh process (:func:`training.memory.peak_memory`); per-sample models get
    :data:`TIMING_SPP` samples per pixel and then every method gets the same frames.  Returns
    {"size": "WxH", "spp": S, "frames": n, "methods": {name: {base_mb, peak_mb, added_mb}}}."""
    from mcdenoise.runtime.denoiser import Denoiser
    from mcdenoise.training.memory import peak_memory

    names = {p: Denoiser.load(p, log=lambda m: None) for p in models}
    spp = TIMING_SPP if any(d.contract.samples_input for d in names.values()) else 0
    w, h = size
    out = {"size": f"{w}x{h}", "spp": spp, "frames": MEMORY_FRAMES, "methods": {}}
    for source, name in [(p, d.contract.spec_name) for p, d in names.items()] + [(b, b) for b in builtins]:
        out["methods"][name] = peak_memory(source, w, h, frames=MEMORY_FRAMES, spp=spp, threads=threads)
        log(f"{name} {w}x{h}: peak {out['methods'][name]['peak_mb']:.0f} MB, "
            f"{out['methods'][name]['added_mb']:.0f} MB added by denoising")
    return out


def flops_part(names: dict, sizes, log, device="cpu"):
    """FLOP counts of every model (``names``: path -> spec name) at each size and 1280x720,
    Open Image Denoise's published U-Net, and this CPU's peak."""
    from mcdenoise.training.flops import count_flops, cpu_peak

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
    p.add_argument("--sizes", nargs="+", type=parse_size, default=None, metavar="WxH",
                   help=f"timing resolutions WxH (default {' '.join(DEFAULT_SIZES)}; --quick: 64x64)")
    p.add_argument("--chart-size", type=parse_size, default=None, metavar="WxH",
                   help=f"resolution of the ms/frame in the chart and table (default {CHART_SIZE}; --quick: 64x64)")
    p.add_argument("--frames", type=int, default=None, help="timed frames per measurement (default 5; --quick 3)")
    p.add_argument("--warmup", type=int, default=None, help="untimed frames first (default 2; --quick 1)")
    add_data(p, required=False, default=f"the sequence test set {SEQUENCES.folder}, rendered if missing; "
                                        f"--quick: {QUICK.folder}")
    p.add_argument("--stills", default=None, metavar="DIR",
                   help=f"folder of sequences whose first frames are the still-frame test set (default "
                        f"{STILLS.folder}, rendered if missing; --quick: the first frames of --data)")
    add_seed(p, "the synthetic timing frames")
    p.add_argument("--no-torch", action="store_true", help="skip torch eager timings")
    p.add_argument("--no-oidn", action="store_true", help="skip Open Image Denoise")
    p.add_argument("--no-quality", action="store_true", help="timing and FLOPs only")
    p.add_argument("--no-memory", action="store_true", help="skip the peak memory of every method")
    p.add_argument("--no-long", action="store_true",
                   help="leave out the long sequences (24 frames at 256x256 with a slow, medium and fast camera; "
                        "rendering them the first time takes hours on 2 cores)")
    p.add_argument("--out", default=None,
                   help="output folder (default docs/results; --quick: runs/bench-quick)")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="cuda: onnxruntime's CUDA provider (needs onnxruntime-gpu), torch and Open Image "
                        "Denoise on the GPU; implies --no-quality (quality does not depend on the device) "
                        "and leaves out svgf (numpy, CPU only) unless --methods names it")
    add_threads(p)




def main(args) -> int:
    from mcdenoise.runtime.cli import command_line

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
        stills=args.stills, data=args.data, quick=q, seed=args.seed, out=out, command=command_line("bench", args),
        device=args.device, long=not args.no_long, memory=not args.no_memory)
    print(f"wrote {out}/bench.md, bench.csv, bench_quality.csv, bench_flops.csv and the charts")
    return 0
