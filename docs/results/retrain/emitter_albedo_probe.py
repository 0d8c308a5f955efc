"""Each shipped model on data/curves-test at 1 spp as the frames are, and with the albedo of
emissive pixels (most first hits flagged emissive) set to 1: relMSE, PSNR, output/reference mean.

    python docs/results/retrain/emitter_albedo_probe.py
"""
import numpy as np
from dataclasses import replace
from mcdenoise.training.evaluate import read_sequences
from mcdenoise.training.methods import load_method
from mcdenoise.training.testsets import at_spp
from mcdenoise.training.metrics import RELMSE_EPS, psnr
seqs = read_sequences("data/curves-test", False)
for path in ("models/wskpn-6.onnx", "models/wskpn-3.onnx", "models/nbg-2l-3g.onnx"):
    for mode in ("as is", "emitter albedo 1"):
        m = load_method(path, threads=2)
        rel, ps, br = [], [], []
        for frames in seqs:
            m.reset()
            for fr in frames:
                f = at_spp(fr, 1)
                if mode != "as is":
                    em = f.sample_feature("emissive").mean(0)      # (H, W, 1) fraction of emissive first hits
                    f = replace(f, albedo=np.where(em > 0.5, np.float32(1.0), f.albedo).astype(np.float32))
                out = m(f); ref = f.reference
                rel.append(np.mean((out - ref) ** 2 / (ref ** 2 + RELMSE_EPS))); ps.append(psnr(out, ref)); br.append(out.mean() / ref.mean())
        print(path, mode, "relMSE %.2f PSNR %.2f out/ref %.3f" % (np.mean(rel), np.mean(ps), np.mean(br)), flush=True)
