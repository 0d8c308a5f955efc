"""Where the gap to Open Image Denoise lives (issue 15): each method's tonemapped squared error
split by the kind of pixel, on the frames after warm-up, with history, as `evaluate` scores them.

    python docs/results/long/error_probe.py /tmp/wskpn-6e-5.onnx oidn-high \\
        --data data/heldout-room_window --spp 1 --warmup 8 > docs/results/long/error_probe.txt

Pixel kinds, from the input frame's own guides at that spp (what a denoiser sees), first match wins:
  emitter  some of the pixel's samples hit a light (emissive > 0);
  edge     a geometric edge within one pixel: depth differs by over EDGE_DEPTH (relative) or
           normals by over EDGE_NORMAL_DEG degrees from a 4-neighbour;
  bright   reference luminance above the frame's 99th percentile (highlights, sun patches);
  flat     the rest.
For each kind: its share of pixels, the method's PSNR over those pixels (ANF Eq. 14, the
metrics module's tonemapping), the share of the method's whole error it holds, and how much of
the gap in mean squared error to the last method (the yardstick, e.g. oidn-high) it holds. Also
the method's brightness: its mean linear radiance over the reference's (1 = energy kept), and
the same over the pixels of each kind, and its PSNR were each frame scaled to the reference's
mean (an oracle: what a bias in brightness costs). Then the error by scale: the PSNR of b x b block means of
the tonemapped images (b in BLOCKS), and the share of the gap in mean squared error to the
yardstick that is left at that scale: error no kernel narrower than b pixels can average away
(blotches, bias, missing light), against fine-grained error (residual noise, lost detail)."""
from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from mcdenoise.runtime.transfer import reinhard_gamma
from mcdenoise.training.methods import load_method
from mcdenoise.training.testsets import at_spp, read_sequences

#: relative depth step across one pixel that counts as a geometric edge
EDGE_DEPTH = 0.05
#: normal turn across one pixel (degrees) that counts as a geometric edge
EDGE_NORMAL_DEG = 25.0
#: reference-luminance percentile above which a pixel counts as bright
BRIGHT_PERCENTILE = 99.0
KINDS = ("emitter", "edge", "bright", "flat")
#: sides of the blocks whose means give the error at coarser and coarser scales
BLOCKS = (4, 8, 16, 32)


def block_means(x: np.ndarray, b: int) -> np.ndarray:
    """(H // b, W // b, C) means of ``x`` (H, W, C) over b x b blocks (a remainder is dropped)."""
    h, w = x.shape[0] // b * b, x.shape[1] // b * b
    return x[:h, :w].reshape(h // b, b, w // b, b, -1).mean(axis=(1, 3))


def _neighbour_max(x: np.ndarray, f) -> np.ndarray:
    """Per pixel, the largest ``f(x[p], x[q])`` over its 4-neighbours q (edges of the frame
    compare with themselves). ``x``: (H, W, C)."""
    pad = np.pad(x, ((1, 1), (1, 1), (0, 0)), mode="edge")
    h, w = x.shape[:2]
    shifts = [pad[0:h, 1:w + 1], pad[2:h + 2, 1:w + 1], pad[1:h + 1, 0:w], pad[1:h + 1, 2:w + 2]]
    return np.max(np.stack([f(x, s) for s in shifts]), axis=0)


def kinds(frame, reference: np.ndarray) -> np.ndarray:
    """(H, W) index into :data:`KINDS` for each pixel of ``frame`` (see module docstring)."""
    depth = frame.depth.astype(np.float64)
    rel = _neighbour_max(depth, lambda a, b: (np.abs(a - b) / np.maximum(np.minimum(a, b), 1e-6))[..., 0])
    n = frame.normal.astype(np.float64)
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)
    turn = _neighbour_max(n, lambda a, b: 1.0 - np.sum(a * b, axis=-1))
    edge = (rel > EDGE_DEPTH) | (turn > 1.0 - np.cos(np.radians(EDGE_NORMAL_DEG)))
    lum = reference @ np.array([0.2126, 0.7152, 0.0722])
    bright = lum > np.percentile(lum, BRIGHT_PERCENTILE)
    emitter = frame.emissive[..., 0] > 0 if frame.emissive is not None else np.zeros_like(edge)
    out = np.full(edge.shape, KINDS.index("flat"), np.int8)
    for k, mask in (("bright", bright), ("edge", edge), ("emitter", emitter)):     # last wins
        out[mask] = KINDS.index(k)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("methods", nargs="+", help="ONNX files and/or method names; the last is the yardstick")
    p.add_argument("--data", required=True)
    p.add_argument("--spp", type=int, default=1)
    p.add_argument("--warmup", type=int, default=8)
    p.add_argument("--threads", type=int, default=0)
    p.add_argument("--blocks", type=int, nargs="+", default=list(BLOCKS), help="block sides of the error by scale")
    a = p.parse_args()
    # labelled by file stem, not by spec name: two runs of one spec are two rows
    methods = [load_method(m, threads=a.threads) for m in a.methods]
    for m, src in zip(methods, a.methods):
        m.label = Path(src).stem if src.endswith(".onnx") else src
    if len({m.label for m in methods}) < len(methods):
        raise SystemExit(f"error_probe: two methods share a label: {[m.label for m in methods]}")
    err = {m.label: np.zeros(len(KINDS)) for m in methods}      # summed tonemapped squared error
    lin = {m.label: np.zeros(len(KINDS)) for m in methods}      # summed linear radiance
    ref_lin, count = np.zeros(len(KINDS)), np.zeros(len(KINDS))
    low = {m.label: {b: [0.0, 0] for b in a.blocks} for m in methods}    # block means' squared error, count
    fair = {m.label: 0.0 for m in methods}       # squared error with each frame's brightness the reference's
    scored = 0
    for frames in read_sequences(a.data):
        for m in methods:
            m.reset()
        for t, fr in enumerate(frames):
            fr_n = at_spp(fr, a.spp)
            outs = {m.label: m(fr_n) for m in methods}
            if t < a.warmup:
                continue
            scored += 1
            k = kinds(replace(fr_n, samples=None), fr_n.reference).ravel()
            count += np.bincount(k, minlength=len(KINDS))
            r = fr_n.reference.reshape(-1, 3).astype(np.float64)
            ref_lin += np.bincount(k, r.sum(-1), minlength=len(KINDS))
            tr = reinhard_gamma(r)
            for name, o in outs.items():
                o = o.reshape(-1, 3).astype(np.float64)
                to = reinhard_gamma(o)
                for b in a.blocks:
                    d = block_means(to.reshape(fr_n.reference.shape), b) - block_means(tr.reshape(fr_n.reference.shape), b)
                    low[name][b][0] += float(np.sum(d * d))
                    low[name][b][1] += d.size
                e = np.mean((to - tr) ** 2, axis=-1)
                scaled = reinhard_gamma(o * (r.sum() / max(o.sum(), 1e-12)))
                fair[name] += float(np.sum(np.mean((scaled - tr) ** 2, axis=-1)))
                err[name] += np.bincount(k, e, minlength=len(KINDS))
                lin[name] += np.bincount(k, o.sum(-1), minlength=len(KINDS))
    yard = methods[-1].label
    print(f"# {a.data}, {a.spp} spp, {scored} frames after {a.warmup} warm-up frames, with history; "
          f"yardstick {yard}")
    print(f"# kinds: emitter (emissive > 0), edge (depth step > {EDGE_DEPTH:.0%} or normal turn > "
          f"{EDGE_NORMAL_DEG:.0f} deg to a 4-neighbour), bright (reference luminance > p{BRIGHT_PERCENTILE:.0f}), flat")
    total = count.sum()
    print("pixels: " + ", ".join(f"{k} {c / total:.1%}" for k, c in zip(KINDS, count)))
    for m in methods:
        e = err[m.label]
        gap_total = e.sum() - err[yard].sum()
        psnr = -10 * np.log10(e.sum() / total)
        print(f"\n{m.label}: PSNR {psnr:.2f} dB, brightness {lin[m.label].sum() / ref_lin.sum():.3f} of the reference's; "
              f"{-10 * np.log10(fair[m.label] / total):.2f} dB with each frame scaled to the reference's brightness (an oracle)")
        print("| kind | PSNR dB | share of its error | brightness | share of the gap to " + yard + " |")
        print("|---|---:|---:|---:|---:|")
        for i, kname in enumerate(KINDS):
            if not count[i]:
                continue
            gap = (e[i] - err[yard][i]) / gap_total if gap_total and m.label != yard else float("nan")
            print(f"| {kname} | {-10 * np.log10(e[i] / count[i]):.2f} | {e[i] / e.sum():.1%} | "
                  f"{lin[m.label][i] / ref_lin[i]:.3f} | {'-' if np.isnan(gap) else format(gap, '.1%')} |")
    mse = {m.label: err[m.label].sum() / total for m in methods}
    print("\nerror by scale: PSNR dB of b x b block means (1: the image)"
          + "".join(f"; {m.label}'s share of its gap to {yard} left at that scale" for m in methods[:-1]))
    print("| b | " + " | ".join(m.label for m in methods) + "".join(f" | {m.label} gap share" for m in methods[:-1]) + " |")
    print("|---:|" + "---:|" * (2 * len(methods) - 1))
    for b in [1] + list(a.blocks):
        e = {n: (mse[n] if b == 1 else low[n][b][0] / low[n][b][1]) for n in mse}
        print(f"| {b} | " + " | ".join(f"{-10 * np.log10(e[m.label]):.2f}" for m in methods)
              + "".join(f" | {(e[m.label] - e[yard]) / (mse[m.label] - mse[yard]):.0%}" for m in methods[:-1]) + " |")


if __name__ == "__main__":
    main()
