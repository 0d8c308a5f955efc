"""One frame of a held-out sequence through each model (with history up to it), as a picture and
as PSNR split by texture: what anf-s does to the long-slow set's checkerboards.

    python docs/results/anf-demod/look.py models/anf-s.onnx /tmp/anf-sd.onnx --data data/long-slow \\
        --spp 8 --frame 19 --out docs/results/anf-demod/long-slow-8spp.png

Picture, top row: the noisy input, each model's output, the reference (Reinhard + gamma, as the
metrics tonemap); bottom row: albedo, normal, each model's absolute tonemapped error x4.
Text: PSNR dB of that frame over textured pixels (the albedo changes by over TEXTURE summed over
channels to the right or below neighbour) and over the rest."""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mcdenoise.runtime.transfer import reinhard_gamma
from mcdenoise.training.methods import load_method
from mcdenoise.training.metrics import psnr
from mcdenoise.training.testsets import at_spp, read_sequences

#: summed absolute albedo step to a neighbour that marks a pixel as textured
TEXTURE = 0.05


def textured(albedo: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels whose albedo (H, W, 3) changes by over TEXTURE (summed over channels)
    to the right or below neighbour."""
    step = np.zeros(albedo.shape[:2])
    step[:, :-1] += np.abs(albedo[:, 1:] - albedo[:, :-1]).sum(-1)
    step[:-1] += np.abs(albedo[1:] - albedo[:-1]).sum(-1)
    return step > TEXTURE


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("models", nargs="+")
    p.add_argument("--data", required=True)
    p.add_argument("--spp", type=int, default=8)
    p.add_argument("--sequence", type=int, default=0)
    p.add_argument("--frame", type=int, default=19, help="frame index (the ones before it build the history)")
    p.add_argument("--threads", type=int, default=0)
    p.add_argument("--out", default=None, help="PNG to write")
    a = p.parse_args()
    methods = [load_method(m, threads=a.threads) for m in a.models]
    frames = list(read_sequences(a.data))[a.sequence]
    for m in methods:
        m.reset()
    for fr in frames[:a.frame + 1]:
        f = at_spp(fr, a.spp)
        outs = [m(f) for m in methods]
    alb = f.albedo.astype(np.float64)
    tex = textured(alb)
    tm = lambda x: reinhard_gamma(np.asarray(x, np.float64))     # noqa: E731
    ref = tm(f.reference)
    print(f"# {a.data} sequence {a.sequence} frame {a.frame}, {a.spp} spp, with history; "
          f"textured pixels {tex.mean():.0%}")
    print("| model | PSNR dB | textured | untextured |")
    print("|---|---:|---:|---:|")
    for name, o in zip(a.models, outs):
        e = ((tm(o) - ref) ** 2).mean(-1)       # metrics.psnr's tonemapped error, per pixel
        db = lambda x: -10 * np.log10(x.mean())       # noqa: E731
        print(f"| {Path(name).stem} | {psnr(o, f.reference):.2f} | {db(e[tex]):.2f} | {db(e[~tex]):.2f} |")
    if a.out:
        from PIL import Image

        top = [tm(f.color)] + [tm(o) for o in outs] + [ref]
        bottom = [np.clip(alb, 0, 1), np.clip(f.normal * 0.5 + 0.5, 0, 1)] + [np.abs(tm(o) - ref) * 4 for o in outs]
        img = np.concatenate([np.concatenate(top, 1), np.concatenate(bottom, 1)], 0)
        Image.fromarray((np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)).save(a.out)


if __name__ == "__main__":
    main()
