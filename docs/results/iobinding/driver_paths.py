"""Whole frames through the driver on the CPU provider, three ways, interleaved frame by frame so
machine noise hits all three alike: numpy prelude with the state on the host (the CPU default),
the prelude graphs with the state on the host, and the prelude graphs with the state kept as
onnxruntime values with IO binding and the frame's layers converted by graphs (a device
provider's default, here with CPU OrtValues).
Prints a markdown table of medians (ms) after the warm-up frames.

    python docs/results/iobinding/driver_paths.py [--size 1280x720] [--frames 10] [--threads 2] MODEL...
"""
import argparse
import statistics

from mcdenoise.runtime.denoiser import Denoiser
from mcdenoise.runtime.frames import Frame
from mcdenoise.training.harness import synthetic_frame

PATHS = (("numpy prelude, host state", "numpy", False), ("prelude graphs, host state", "graph", False),
         ("prelude graphs, IO binding", "graph", True))

p = argparse.ArgumentParser()
p.add_argument("models", nargs="+")
p.add_argument("--size", default="1280x720")
p.add_argument("--frames", type=int, default=10)
p.add_argument("--warmup", type=int, default=2)
p.add_argument("--threads", type=int, default=2)
p.add_argument("--spp", type=int, default=0, help="per-sample features per frame (per-sample models)")
a = p.parse_args()
w, h = (int(v) for v in a.size.split("x"))
print(f"| model | path | preprocess | reproject | graph | postprocess | whole frame |  ({a.size}, {a.threads} threads, medians of "
      f"{a.frames - a.warmup} frames)")
print("|---|---|---:|---:|---:|---:|---:|")
for model in a.models:
    dens = [Denoiser.load(model, threads=a.threads, prelude=pre, io_binding=io, log=lambda m: None)
            for _, pre, io in PATHS]
    for t in range(a.frames):
        fr = synthetic_frame(w, h, t, 0, a.spp)
        for den in dens:
            den(Frame(**fr))
    for (name, _, _), den in zip(PATHS, dens):
        rows = den.timings[a.warmup:]
        med = {k: statistics.median(r[k] for r in rows) for k in ("preprocess", "reproject", "graph (wall)", "postprocess", "total")}
        print(f"| {model} | {name} | {med['preprocess']:.1f} | {med['reproject']:.1f} | {med['graph (wall)']:.1f} | {med['postprocess']:.1f} | {med['total']:.1f} |")
