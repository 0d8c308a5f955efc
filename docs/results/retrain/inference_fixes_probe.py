"""Fixes of the emitter halo tried at inference, without retraining: each shipped model and Open
Image Denoise on data/curves-test at 1 spp, with the frames as they are; with the albedo of
emissive pixels (most first hits flagged emissive) set to 1; and with the first-hit emission
filtered apart (the colour fed is the colour less the emission, per pixel the mean over samples
of radiance x emissive flag, and the emission is added back to the output, as it is or through a
3x3 box filter). relMSE, PSNR, output/reference mean.

    python docs/results/retrain/inference_fixes_probe.py
"""
from dataclasses import replace

import numpy as np

from mcdenoise.training.evaluate import read_sequences
from mcdenoise.training.methods import load_method
from mcdenoise.training.metrics import RELMSE_EPS, psnr
from mcdenoise.training.testsets import at_spp

seqs = read_sequences("data/curves-test", False)
for path in ("models/wskpn-6.onnx", "models/wskpn-3.onnx", "models/nbg-2l-3g.onnx", "oidn-high"):
    for mode in ("as is", "emitter albedo 1", "emission apart", "emission apart, 3x3 box"):
        m = load_method(path, threads=2)
        rel, ps, br = [], [], []
        for frames in seqs:
            m.reset()
            for fr in frames:
                f = at_spp(fr, 1)
                emission = np.zeros_like(f.color)
                if mode == "emitter albedo 1":
                    em = f.sample_feature("emissive").mean(0)
                    f = replace(f, albedo=np.where(em > 0.5, np.float32(1.0), f.albedo).astype(np.float32))
                elif mode != "as is":
                    emission = (f.sample_feature("radiance") * f.sample_feature("emissive")).mean(0).astype(np.float32)
                    f = replace(f, color=np.maximum(f.color - emission, 0).astype(np.float32))
                    if "box" in mode:   # partial coverage at a light's border, as the reference has it
                        pad = np.pad(emission, ((1, 1), (1, 1), (0, 0)), mode="edge")
                        emission = sum(pad[dy:dy + f.color.shape[0], dx:dx + f.color.shape[1]]
                                       for dy in range(3) for dx in range(3)) / np.float32(9)
                out = m(f) + emission
                ref = f.reference
                rel.append(np.mean((out - ref) ** 2 / (ref ** 2 + RELMSE_EPS)))
                ps.append(psnr(out, ref))
                br.append(out.mean() / ref.mean())
        print(f"{path} {mode}: relMSE {np.mean(rel):.2f} PSNR {np.mean(ps):.2f} output/reference {np.mean(br):.3f}",
              flush=True)
