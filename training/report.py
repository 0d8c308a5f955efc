"""The measuring side's report: the markdown tables, CSV files, charts and crops that ``bench``
and ``stress`` write, with the paths and command lines they quote.

Paths in the written files are relative to the current directory (where the command ran) when
they lie under it, so a report written from the checkout reads the same on any machine."""
from __future__ import annotations

import csv
import math
import os
import subprocess
from pathlib import Path

import numpy as np

from mcdenoise.runtime import DATA_ROOT, timing
from mcdenoise.runtime.writers import write_png
from mcdenoise.runtime.transfer import reinhard_gamma
from mcdenoise.training.methods import WithoutHistory
from mcdenoise.training.scoring import pareto_front

def rel_path(path, base: str | os.PathLike | None = None) -> str:
    """``path`` relative to ``base`` (default: the current directory) when it lies under it,
    else as given."""
    try:
        p, root = Path(path).resolve(), Path(base or os.getcwd()).resolve()
        return os.path.relpath(p, root) if base else str(p.relative_to(root))
    except ValueError:
        return str(path)


def rel_command(cmd: str) -> str:
    """A command line with the current directory's prefix dropped from its paths."""
    return cmd.replace(os.getcwd().rstrip(os.sep) + os.sep, "")


# ---- bench: tables, CSVs, charts

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
    (out / "bench.md").write_text(bench_markdown(res))


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
    keys = ["method", "set", "spp", "psnr", "ssim", "flip", "smape", "relmse", "trmae", "wte", "frames",
            "ms_per_frame", "timing_size"]
    with open(path, "w", newline="") as fh:
        _csv_header(fh, res)
        wr = csv.DictWriter(fh, fieldnames=keys)
        wr.writeheader()
        for (kind, spp), per in res["quality"].items():
            for m, v in per.items():
                for label, row in ((kind, v), (kind + " after warm-up", v.get("after_warmup"))):
                    if row:
                        wr.writerow({"method": m, "set": label, "spp": spp, **{k: row.get(k) for k in keys[3:11]},
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


def _long_tables(res, order, prefix: str = "long-", title: str = "Long sequences") -> list[str]:
    """The long sequences' table per spp: PSNR over all frames and after the warm-up, TRMAE
    and the warped temporal error after it, one column group per set (camera speed, or
    held-out scene with ``prefix="heldout-"``)."""
    q, ts = res["quality"], res["testsets"]
    sets = [k for k in ts if isinstance(k, str) and k.startswith(prefix) and ":" not in k]
    if not sets:
        return []
    first = ts[sets[0]]
    cut = len(prefix)
    L = [f"### {title}", "",
         f"{first['sequences']} sequences x {first['frames'] // max(1, first['sequences'])} frames at {first['size']} "
         f"per set ({', '.join(s[cut:] for s in sets)}: " + ", ".join(f"`{ts[s]['folder']}`" for s in sets)
         + f"; reference {first['ref_spp']} spp, scene seeds {_seeds(first['scene_seeds'])}), every method with its "
         f"history, reset at each sequence's start. 'all': PSNR over every frame; 'after': over the frames after the "
         f"first {first['warmup']} of each sequence, as a real-time user sees it, with TRMAE (ANF Eq. 16) and WTE, the "
         "warped temporal error (`training.metrics.warped_temporal_error`: the previous output warped along the true "
         "motion against the current, relative to the same for the reference; 1 is as steady as the reference, more "
         "is flicker, less is lag) over the same frames. Rows '(no history)': the same model reset before "
         "every frame, so the difference is what its history earns."]
    refs = {s: ts.get(f"{s}:reference_db") for s in sets}
    if any(v is not None for v in refs.values()):
        L[-1] += (" Reference check (`mcdenoise render ... --check-references`: a second reference of each first "
                  "frame from independent seeds): the two agree to at least " + ", ".join(
                      f"{v:.1f} dB ({s[cut:]})" for s, v in refs.items() if v is not None)
                  + "; a method's PSNR near that is limited by the reference, not the method.")
    L.append("")
    spps = sorted({spp for (kind, spp) in q if kind in sets})
    for spp in spps:
        head = "| method | " + " | ".join(f"{s[cut:]} PSNR all | after | TRMAE | WTE" for s in sets) + " |"
        L += [f"{spp} spp:", "", head, "|---|" + "---:|" * (4 * len(sets))]
        bare = [m + WithoutHistory.SUFFIX for m in order if any(m + WithoutHistory.SUFFIX in q.get((s, spp), {})
                                                               for s in sets)]
        for m in [*order, *bare]:
            cells = []
            for s in sets:
                v = q.get((s, spp), {}).get(m)
                a = (v or {}).get("after_warmup") or {}
                cells += [_fmt((v or {}).get("psnr")), _fmt(a.get("psnr")), _fmt(a.get("trmae"), ".3f"),
                          _fmt(a.get("wte"), ".3f")]
            if any(c != "-" for c in cells):
                L.append(f"| {m} | " + " | ".join(cells) + " |")
        L.append("")
    return L


def bench_markdown(res) -> str:
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
        L += _long_tables(res, order)
        L += _long_tables(res, order, "heldout-", "Held-out scenes made by hand (never trained on)")
        L += ["### All metrics", ""]
        for (kind, spp), per in q.items():
            L += [f"{kind}, {spp} spp:", "", "| method | PSNR dB | SSIM | FLIP | SMAPE | relMSE | TRMAE | WTE |",
                  "|---|---:|---:|---:|---:|---:|---:|---:|"]
            for m in order:
                if m in per:
                    v = per[m]
                    L.append(f"| {m} | {v['psnr']:.2f} | {_fmt(v['ssim'], '.4f')} | {_fmt(v['flip'], '.4f')} | "
                             f"{v['smape']:.4f} | {v['relmse']:.4f} | {_fmt(v['trmae'], '.4f')} | "
                             f"{_fmt(v.get('wte'), '.3f')} |")
            L.append("")

    # compute
    L += ["## Compute: FLOPs, parameters, achieved throughput", "",
          f"Counting rules: `training/flops.py` (ONNX shape inference at the frame size; Conv FMAs = "
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
          "onnxruntime graph stages are profiler kernel sums; driver stages (preprocess, reproject, "
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
    sc = res.get("spp_scaling") or {}
    if sc.get("models"):
        spps = sc["spp"]
        L += ["", f"## Per-sample models against samples per pixel, {sc['size']}", "",
              "Median ms per stage, a fresh driver at each S on the same synthetic frames, and the ratio of "
              f"the last to the first S ({spps[-1]}x the samples): a stage that reads every sample grows "
              "about as fast as S (less its fixed cost), one after the average over samples stays near 1.", ""]
        for name, stages in sc["models"].items():
            L += [f"{name}:", "", "| stage | " + " | ".join(f"{s} spp" for s in spps) + f" | {spps[-1]}/{spps[0]} |",
                  "|---|" + "---:|" * (len(spps) + 1)]
            for st, ms in stages.items():
                ratio = f"{ms[-1] / ms[0]:.2f}" if ms[0] and ms[-1] is not None else "-"
                L.append(f"| {st} | " + " | ".join(_fmt(m, ".1f") for m in ms) + f" | {ratio} |")
            L.append("")
    mem = res.get("memory")
    if mem:
        samples = f" with {mem['spp']} samples per pixel" if mem["spp"] else ""
        L += ["", f"## Peak memory at {mem['size']}", "",
              f"Each method alone in a fresh process (`python -m mcdenoise.training.memory`), {mem['frames']} "
              f"frames{samples}: the process's peak resident set, and what denoising added to the peak "
              "once the frames were built and the method loaded.", "",
              "| method | peak MB | added by denoising MB |", "|---|---:|---:|"]
        for m, v in mem["methods"].items():
            L.append(f"| {m} | {v['peak_mb']:.0f} | {v['added_mb']:.0f} |")
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


def _seeds(seeds) -> str:
    if not seeds:
        return "?"
    return f"{seeds[0]}-{seeds[-1]}" if len(seeds) > 1 else str(seeds[0])


def _paper(path) -> dict:
    from mcdenoise.runtime.denoiser import Denoiser

    return Denoiser.load(path, log=lambda m: None).contract.paper or {}


# ---- stress: crops of the worst regions, CSV, tables

def error_map(out: np.ndarray, ref: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Per-pixel squared error of tonemapped radiance (ANF Eq. 15), mean over channels (H, W)."""
    o = np.nan_to_num(out.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0) * scale
    d = reinhard_gamma(o) - reinhard_gamma(ref.astype(np.float64) * scale)
    return (d * d).mean(axis=-1)


def worst_window(maps: dict, size: int) -> tuple:
    """(key, y, x) of the size x size window with the largest sum over ``maps`` {key: (H, W)}."""
    best = (-math.inf, None, 0, 0)
    for k, m in maps.items():
        h, w = m.shape
        s = min(size, h, w)
        c = np.zeros((h + 1, w + 1))
        c[1:, 1:] = m.cumsum(0).cumsum(1)
        win = c[s:, s:] - c[:-s, s:] - c[s:, :-s] + c[:-s, :-s]
        y, x = np.unravel_index(int(np.argmax(win)), win.shape)
        if win[y, x] > best[0]:
            best = (float(win[y, x]), k, int(y), int(x))
    return best[1], best[2], best[3]


def display(img: np.ndarray | None, scale: float, shape) -> np.ndarray:
    """Tonemapped [0, 1] panel; non-finite pixels magenta, a missing output grey."""
    if img is None:
        return np.full(shape, 0.5)
    img = img.astype(np.float64) * scale
    bad = ~np.isfinite(img).all(axis=-1)
    out = reinhard_gamma(np.nan_to_num(img, nan=0.0, posinf=0.0, neginf=0.0))
    out[bad] = (1.0, 0.0, 1.0)
    return out


def compose(rows: list[tuple[str, list]], labels: list[str], path: str, zoom: int) -> None:
    """Write a PNG grid: one row per (row label, [panel (h, w, 3) in [0, 1]]), columns labelled.
    Panels are enlarged ``zoom`` x (nearest).  Labels need matplotlib; without it, none."""
    ph, pw = rows[0][1][0].shape[:2]
    ph, pw = ph * zoom, pw * zoom
    gap, top, left = 2, 14, 72
    width = left + len(labels) * (pw + gap)
    height = top + len(rows) * (ph + gap)
    canvas = np.ones((height, width, 3))
    for r, (_, panels) in enumerate(rows):
        for c, p in enumerate(panels):
            y, x = top + r * (ph + gap), left + c * (pw + gap)
            canvas[y:y + ph, x:x + pw] = np.repeat(np.repeat(p, zoom, 0), zoom, 1)
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        write_png(path, canvas)
        return
    fig = Figure(figsize=(width / 100, height / 100), dpi=100)
    FigureCanvasAgg(fig)
    fig.figimage(canvas, 0, 0, origin="upper")
    for c, lab in enumerate(labels):
        fig.text((left + c * (pw + gap) + pw / 2) / width, 1 - 2 / height, lab, ha="center", va="top", fontsize=7)
    for r, (lab, _) in enumerate(rows):
        fig.text(2 / width, 1 - (top + r * (ph + gap) + ph / 2) / height, lab, ha="left", va="center", fontsize=7)
    fig.canvas.draw()
    img = np.asarray(fig.canvas.buffer_rgba())[..., :3]
    write_png(path, img.astype(np.float64) / 255.0)




CSV_FIELDS = ("case", "method", "clean_counterpart", "psnr_clean", "psnr_case", "delta_db",
              "relmse_clean", "relmse_case", "nonfinite_output_values", "driver_resets", "error",
              "failed", "skipped")


def write_stress_csv(summary: dict, path: Path) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_FIELDS)
        for case in summary["cases"]:
            for m in summary["methods"]:
                r = summary["table"][(case.name, m)]
                f = lambda v: "" if v is None else (f"{v:.4f}" if isinstance(v, float) else v)
                w.writerow([case.name, m, case.vs or case.clean, f(r.get("psnr_clean")), f(r.get("psnr_case")),
                            f(r.get("delta_db")), f(r.get("relmse_clean")), f(r.get("relmse_case")),
                            f(r.get("nonfinite")), f(r.get("resets")), r.get("error") or "",
                            r.get("failed") or "", r.get("skipped") or ""])


def _cell(r: dict) -> str:
    if r.get("skipped"):
        return "skipped"
    if r.get("error"):
        return "**crash**"
    txt = f"{r['delta_db']:+.2f}"
    if r.get("nonfinite"):
        txt += " NaN"
    return f"**{txt} fail**" if r.get("failed") else txt


def stress_markdown(summary: dict, out: Path) -> str:
    from mcdenoise.runtime.timing import cpu_name

    names, table = summary["methods"], summary["table"]
    L = ["# Stress test", "",
         "What each method loses on hard input, against the same method on the clean counterpart "
         "(`mcdenoise stress`, `training/stress.py`, issue #5).", "",
         "Command:", "", "```", summary["command"], "```", "",
         f"Machine: {cpu_name()}; {summary['seconds']} s for the whole run. Clean case: {summary['spp']} spp "
         f"from `{rel_path(summary['data'])}`" + (" (--quick: 2 sequences x 2 frames)" if summary["quick"] else "") + ".",
         "",
         "## PSNR change (dB) against the clean counterpart", "",
         "PSNR is ANF Eq. 14 (tonemapped, over all scored frames of the case); non-finite output "
         "values are counted and scored as 0. `fail` follows the rule below; `NaN`: the output had "
         "non-finite values; the noisy input is the yardstick and never judged.", "",
         "| case | vs | frames | " + " | ".join(names) + " |",
         "|---|---|---:|" + "---:|" * len(names)]
    clean = summary["clean"]
    L.append(f"| *clean, absolute dB* | - | {summary['clean_frames']} | "
             + " | ".join("-" if clean[m] is None else f"{clean[m]['psnr']:.2f}" for m in names) + " |")
    for case in summary["cases"]:
        L.append(f"| {case.name} | {case.vs or case.clean} | {summary['frames'].get(case.name, '-')} | "
                 + " | ".join(_cell(table[(case.name, m)]) for m in names) + " |")
    L += ["", "relMSE on the case / relMSE on the clean counterpart (1: no change):", "",
          "| case | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for case in summary["cases"]:
        if case.skipped:
            continue
        cells = []
        for m in names:
            r = table[(case.name, m)]
            cells.append("-" if r.get("error") or not r.get("relmse_clean") else f"{r['relmse_case'] / r['relmse_clean']:.2f}")
        L.append(f"| {case.name} | " + " | ".join(cells) + " |")
    L += ["", "## Cases", "", "| case | what | clean counterpart | worst region (crop) |", "|---|---|---|---|"]
    for case in summary["cases"]:
        c = summary["crops"].get(case.name)
        crop = "-" if case.skipped else "none"
        if c:
            crop = (f"[{Path(c['path']).name}]({rel_path(c['path'], out)}) ({c['method']}, sequence {c['frame'][0]} "
                    f"frame {c['frame'][1]}, x {c['x']} y {c['y']}, {c['size']} px)")
        L.append(f"| {case.name} | {case.what}{' (skipped: ' + case.skipped + ')' if case.skipped else ''} | "
                 f"{case.vs or case.clean} | {crop} |")
    L += ["", "Crops: columns are the input, each method and the reference, tonemapped (ANF Eq. 15) "
          "after undoing the exposure; non-finite pixels are magenta. The window (size above, "
          "enlarged with nearest neighbours) is where the method that lost the most beyond the noisy input "
          "has the largest error increase over its own clean output (perturbation cases, second "
          "row: the clean counterpart) or the largest error (rendered cases).", "",
          "## Failure rule", "",
          f"A method fails a case when it crashes, when any output value is non-finite, when its PSNR on "
          f"the case is below the noisy input's, or when its PSNR change is more than {summary['fail_margin_db']:g} dB "
          f"below the noisy input's own change (`training/stress.py`, `judge`).", ""]
    fails = [(c.name, m, table[(c.name, m)]["failed"]) for c in summary["cases"] for m in names
             if table[(c.name, m)].get("failed")]
    L += ["## Failures", ""]
    if fails:
        for m in names:
            mine = [(c, why) for c, mm, why in fails if mm == m]
            if mine:
                L.append(f"- **{m}**: " + "; ".join(f"{c} ({why})" for c, why in mine))
    else:
        L.append("None.")
    notes = []
    for c in summary["cases"]:
        nd = table.get((c.name, "noisy"), {}).get("delta_db")
        for m in names:
            r = table[(c.name, m)]
            if m == "noisy" or r.get("failed") or r.get("delta_db") is None or nd is None:
                continue
            if r["delta_db"] - nd < -summary['note_margin_db']:
                notes.append(f"{m} on {c.name} ({r['delta_db'] - nd:+.1f} dB)")
    if notes:
        L += ["", f"Losses of more than {summary['note_margin_db']:g} dB beyond the noisy input's that are not failures: "
              + "; ".join(notes) + "."]
    errors = {(c.name, m): table[(c.name, m)]["error"] for c in summary["cases"] for m in names
              if table[(c.name, m)].get("error")}
    if errors:
        L += ["", "Errors:", ""]
        seen = set()
        for (c, m), e in errors.items():
            if (m, e) in seen:
                continue
            seen.add((m, e))
            L.append(f"- {m} ({c}{' and others' if sum(1 for (cc, mm), ee in errors.items() if mm == m and ee == e) > 1 else ''}): `{e}`")
    L += ["", "## Absolute scores", "", "| case | method | PSNR clean | PSNR case | relMSE clean | relMSE case | driver resets |",
          "|---|---|---:|---:|---:|---:|---:|"]
    for case in summary["cases"]:
        for m in names:
            r = table[(case.name, m)]
            if r.get("skipped") or r.get("error"):
                continue
            L.append(f"| {case.name} | {m} | {r['psnr_clean']:.2f} | {r['psnr_case']:.2f} | "
                     f"{r['relmse_clean']:.4g} | {r['relmse_case']:.4g} | {'-' if r.get('resets') is None else r['resets']} |")
    L += ["", "## Data", ""]
    if summary["sets"]:
        L += ["| set | folder | scene seeds | frames | render s (s/frame) | command |", "|---|---|---|---:|---:|---|"]
        for name, info in summary["sets"].items():
            if not info.get("folder"):
                L.append(f"| {name} | not rendered | - | - | - | `{info['command']}` |")
                continue
            L.append(f"| {name} | `{rel_path(info['folder'])}` | {', '.join(map(str, info.get('seeds', [])))} | "
                     f"{info.get('frames', '-')} | {info.get('render_seconds', '-')} ({info.get('seconds_per_frame', '-')}) | "
                     f"`{rel_command(info['command'])}` |")
        L.append("")
    else:
        L += ["No rendered sets (--data only).", ""]
    L += [f"Perturbation seeds: numpy `default_rng([{summary['seed']}, case, sequence, frame])`. "
          "Render seconds are the renderer's own (manifest), on this machine.", ""]
    code = code_version()
    if code:
        L += [f"Code: {code}.", ""]
    return "\n".join(L)


def code_version() -> str | None:
    """"commit abc1234" plus the runtime/method files that differ from it, or None without git."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=DATA_ROOT, capture_output=True,
                              text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "runtime", "models", "training/stress.py"],
                               cwd=DATA_ROOT, capture_output=True, text=True, timeout=10).stdout.split("\n")
    except (OSError, subprocess.SubprocessError):
        return None
    if not head:
        return None
    changed = sorted(line[3:] for line in dirty if line.strip())
    return f"commit {head}" + (f" with uncommitted {', '.join(changed)}" if changed else "")


