"""The stress test's 1-spp relMSE of the NBG files (docs/results/stress.md): where it comes from.
Runs each file through the driver on data/stress/base (3 sequences x 4 frames, 128x128, from a reset
per sequence) at 1 and 4 spp and prints the mean relMSE (as training.metrics, per pixel
(out - ref)^2 / (ref^2 + 0.01), mean over channels and pixels, then frames) and the two worst frames:
(frame relMSE, sequence, frame, y, x, worst pixel's relMSE, output, reference, albedo, noisy colour there).

    python docs/results/nbg-retrain/bright_pixels.py > docs/results/nbg-retrain/bright_pixels.txt
(the zero-shot file: docs/results/nbg-retrain/common.sh's zero_shot, made first if missing)
"""
import subprocess

import numpy as np

from mcdenoise.runtime.denoiser import Denoiser
from mcdenoise.training.testsets import at_spp, read_sequences

zero = subprocess.run(["bash", "-c", ". docs/results/nbg-retrain/common.sh && zero_shot nbg-2l-3g-aa"],
                      capture_output=True, text=True, check=True).stdout.strip()
files = {"nbg-2l-3g-aa (retrained, shipped)": "models/nbg-2l-3g-aa.onnx",
         "nbg-2l-3g-aa zero-shot": zero, "nbg-2l-3g": "models/nbg-2l-3g.onnx"}
seqs = read_sequences("data/stress/base")
for name, f in files.items():
    den = Denoiser.load(f, threads=1)
    for spp in (1, 4):
        rows = []
        for si, seq in enumerate(seqs):
            den.reset()
            for t, fr in enumerate(seq):
                fr_n = at_spp(fr, spp)
                out, ref = den(fr_n), fr_n.reference
                e = ((out - ref) ** 2 / (ref ** 2 + 1e-2)).mean(-1)
                y, x = np.unravel_index(np.argmax(e), e.shape)
                rows.append((round(float(e.mean()), 3), si, t, int(y), int(x), round(float(e.max())),
                             out[y, x].round(2).tolist(), ref[y, x].round(2).tolist(),
                             fr_n.albedo[y, x].round(2).tolist(), fr_n.color[y, x].round(2).tolist()))
        rows.sort(reverse=True)
        print(f"{name}, {spp} spp: mean relMSE {np.mean([r[0] for r in rows]):.3f}")
        for r in rows[:2]:
            print("   ", r)
