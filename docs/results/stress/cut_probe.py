"""Why anf-s lost 2.35 dB on the stress test's unflagged cut (README, stress): at each cut between
the base set's sequences (no meta["cut"], valid set to 1, zero motion), the share of pixels the
history test keeps, and each model's PSNR at the cut frame with the history against reset, with
the MSE split into the kept and the dropped pixels, with the driver's auto-exposure and without. CUT_HISTORY is set to 0 here, so the driver
does not find the cut itself (what it did before it could).

    python docs/results/stress/cut_probe.py [data/stress/base]   > docs/results/stress/cut_probe.txt
"""
import mcdenoise.runtime.denoiser as driver
driver.CUT_HISTORY = 0.0
import numpy as np
from dataclasses import replace
from mcdenoise.training.testsets import read_sequences, at_spp
from mcdenoise.runtime.denoiser import Denoiser
from mcdenoise.runtime.frames import Frame
from mcdenoise.runtime.inputs import frame_planes
from mcdenoise.runtime.temporal import reproject
from mcdenoise.training.metrics import psnr
import sys; seqs = read_sequences(sys.argv[1] if len(sys.argv) > 1 else "data/stress/base")
clean = [[at_spp(f, 4) for f in s] for s in seqs]
for a, b in zip(clean[:-1], clean[1:]):
    last, first = a[-1], b[0]
    first = replace(first, meta=dict(first.meta, cut=False), valid=None if first.valid is None else np.ones_like(first.valid))
    g = lambda f: {k: v for k, v in frame_planes(f, [n for n in ("depth", "position", "normal") if getattr(f, n) is not None]).items()}
    cur, prev = g(first), g(last)
    motion = np.zeros((1, 2, *first.size), np.float32)
    _, hist = reproject([np.ones((1, 1, *first.size), np.float32)], motion, cur, prev)
    print("history kept after the unflagged cut:", float(hist.mean()))
    for model, auto in [(m, a) for m in ("models/anf-s.onnx", "models/wskpn-3.onnx", "models/nbg-2l-1g.onnx")
                        for a in (True, False)]:
        den = Denoiser.load(model, log=lambda m: None, autoexposure=auto)
        for f in a: den(f)
        with_h = den(first)
        den.reset(); no_h = den(first)
        ref = first.reference
        m = hist[0, 0] > 0
        tm = lambda x: psnr(x, ref)
        err = lambda x, mask: float(np.mean(((x - ref) ** 2)[mask]))
        print(model, "auto-exposure" if auto else "exposure 1", "PSNR with/without history %.2f / %.2f" % (tm(with_h), tm(no_h)),
              "MSE on kept pixels %.4g / %.4g, on dropped %.4g / %.4g" % (err(with_h, m), err(no_h, m), err(with_h, ~m), err(no_h, ~m)))
