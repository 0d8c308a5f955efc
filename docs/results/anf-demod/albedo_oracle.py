"""Does the noisy albedo layer cost anf-sd its temporal stability?  Runs a model over a held-out
set at --spp three times: as the runtime feeds it; with every frame's albedo layer replaced by
the mean of all 8 stored samples' albedo (an oracle: a cleaner albedo to demodulate and
re-modulate by, everything else at --spp); and with the albedo layer accumulated over frames
(reprojected with the driver's own `runtime.temporal.reproject` and consistency test, blended
at --alpha as the colour history is: what a model could do without an oracle).  Scores as
`mcdenoise evaluate` does, after --warmup frames.

    python docs/results/anf-demod/albedo_oracle.py /tmp/anf-sd.onnx --data data/long-slow --spp 1 \\
        > docs/results/anf-demod/albedo_oracle.txt"""
from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from mcdenoise.runtime.inputs import frame_inputs
from mcdenoise.runtime.temporal import accumulate, reproject
from mcdenoise.training.methods import load_method
from mcdenoise.training.scoring import score
from mcdenoise.training.testsets import at_spp, read_sequences


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("model")
    p.add_argument("--data", required=True)
    p.add_argument("--spp", type=int, default=1)
    p.add_argument("--warmup", type=int, default=8)
    p.add_argument("--threads", type=int, default=0)
    p.add_argument("--alpha", type=float, default=0.2, help="the accumulated albedo's current-frame weight")
    a = p.parse_args()
    m = load_method(a.model, threads=a.threads)
    seqs = list(read_sequences(a.data))
    print(f"# {a.model} on {a.data} at {a.spp} spp, with history, after {a.warmup} warm-up frames")
    print("| albedo layer | PSNR dB | TRMAE | WTE |")
    print("|---|---:|---:|---:|")
    for mode in ("fed", "oracle", "accumulated"):
        outs, refs, inputs, keep_lengths = [], [], [], []
        for frames in seqs:
            m.reset()
            acc, prev = None, None
            for t, fr in enumerate(frames):
                f = at_spp(fr, a.spp)
                if mode == "oracle":
                    f = replace(f, albedo=at_spp(fr, 8).albedo)
                elif mode == "accumulated":
                    g = frame_inputs(f, ["motion", "position", "depth"])
                    cur = {"depth": g["depth"], "position": g["position"],
                           "normal": np.ascontiguousarray(f.normal.transpose(2, 0, 1)[None], np.float32)}
                    alb = np.ascontiguousarray(f.albedo.transpose(2, 0, 1)[None], np.float32)
                    if acc is None:
                        acc = alb
                    else:
                        (warped,), history = reproject([acc], g["motion"], cur, prev)
                        acc = accumulate(alb, warped, history, a.alpha)
                    prev = cur
                    f = replace(f, albedo=acc[0].transpose(1, 2, 0).copy())
                o = m(f)
                if t >= a.warmup:
                    outs.append(o)
                    refs.append(f.reference)
                    inputs.append(replace(f, samples=None))
            keep_lengths.append(max(0, len(frames) - a.warmup))
        r = score(outs, refs, keep_lengths, which=("psnr", "trmae", "wte"), frames=inputs)
        label = {"fed": f"{a.spp} spp (as fed)", "oracle": "8-spp mean (oracle)",
                 "accumulated": f"{a.spp} spp accumulated (alpha {a.alpha})"}[mode]
        print(f"| {label} | {r['psnr']:.2f} | "
              f"{r['trmae']:.3f} | {r['wte']:.3f} |")


if __name__ == "__main__":
    main()
