"""Fine detail: energy of the 5x5 high-pass of the tonemapped output against the reference's, and their
correlation, over the frames after warm-up (less energy than the reference: detail blurred away; low
correlation: the detail is not the reference's, i.e. residual noise). argv: data spp warm-up methods...

    python docs/results/emitters/probe/detail.py data/long-slow 1 8 models/wskpn-4x3-aa.onnx oidn-fast
"""
import sys, numpy as np
from mcdenoise.training.testsets import read_sequences, at_spp
from mcdenoise.training.methods import load_method
from mcdenoise.runtime.transfer import reinhard_gamma
data, spp, warm = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
methods = [load_method(n, threads=2) for n in sys.argv[4:]]
acc = {m.name: np.zeros(3) for m in methods}
def box5(x):
    """5x5 mean of (H, W, C), edges replicated (as scipy.ndimage.uniform_filter's "reflect" near enough)."""
    p = np.pad(x, ((2, 2), (2, 2), (0, 0)), mode="edge")
    return sum(p[dy:dy + x.shape[0], dx:dx + x.shape[1]] for dy in range(5) for dx in range(5)) / 25.0


hp = lambda x: x - box5(x)  # noqa: E731
for frames in read_sequences(data):
    for m in methods: m.reset()
    for t, fr in enumerate(frames):
        f = at_spp(fr, spp)
        outs = {m.name: m(f) for m in methods}
        if t < warm: continue
        r = hp(reinhard_gamma(f.reference))
        for k, o in outs.items():
            h = hp(reinhard_gamma(o))
            acc[k] += [(h * h).sum(), (r * r).sum(), (h * r).sum()]
for k, (o, r, c) in acc.items():
    print(f"{k:30s} HF energy out {o:.1f} ref {r:.1f} cross {c:.1f} -> HF error {o + r - 2*c:.1f}; out/ref {o/r:.2f}, corr {c/np.sqrt(o*r):.2f}")
