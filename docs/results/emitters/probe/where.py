"""Where does a model lose to Open Image Denoise? The tonemapped squared error (ANF Eq. 15) of the frames
after warm-up, split by pixel kind: misses (depth 0, the sky), lights (emissive > 0), bright (reference > 2),
depth edges (a 5% depth step to a 4-neighbour), albedo edges (albedo step > 0.1), the rest (flat). Printed as
the sum over each kind / all pixels (x 1e-3), so the rows add up to the MSE. argv: data spp warm-up methods...

    python docs/results/emitters/probe/where.py data/long-slow 1 8 models/wskpn-4x3-aa.onnx oidn-fast
"""
import sys, numpy as np
from mcdenoise.training.testsets import read_sequences, at_spp
from mcdenoise.training.methods import load_method
from mcdenoise.runtime.transfer import reinhard_gamma
data, spp, warm = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
names = sys.argv[4:]
methods = [load_method(n, threads=2) for n in names]
seqs = read_sequences(data)
se = {m.name: [] for m in methods}; cats = []
for frames in seqs:
    for m in methods: m.reset()
    for t, fr in enumerate(frames):
        f = at_spp(fr, spp)
        outs = {m.name: m(f) for m in methods}
        if t < warm: continue
        ref = f.reference
        for k, o in outs.items():
            se[k].append(((reinhard_gamma(o) - reinhard_gamma(ref)) ** 2).mean(-1))
        d = f.depth[..., 0]; e = f.emissive[..., 0] if f.emissive is not None else np.zeros_like(d)
        a = f.albedo.mean(-1); r = ref.mean(-1)
        # depth edges: relative depth jump to any 4-neighbour > 5%
        dd = np.zeros_like(d, bool)
        for ax in (0, 1):
            g = np.abs(np.diff(d, axis=ax)) / np.maximum(np.minimum(np.delete(d, -1, ax), np.delete(d, 0, ax)), 1e-3) > 0.05
            if ax == 0: dd[:-1] |= g; dd[1:] |= g
            else: dd[:, :-1] |= g; dd[:, 1:] |= g
        ga = np.zeros_like(a)
        ga[:, 1:] += np.abs(np.diff(a, axis=1)); ga[1:] += np.abs(np.diff(a, axis=0))
        cat = np.full(d.shape, 5, np.int8)      # 5 flat
        cat[ga > 0.1] = 4                       # texture edges
        cat[dd] = 3                             # depth edges
        cat[r > 2] = 2                          # bright
        cat[e > 0] = 1                          # lights
        cat[d <= 0] = 0                         # misses (sky)
        cats.append(cat)
C = np.stack(cats); labels = ["miss", "light", "bright>2", "depth edge", "albedo edge", "flat"]
tot = {k: np.stack(v).sum() for k, v in se.items()}
npx = C.size
print("category share-of-pixels " + " ".join(f"{k}" for k in se))
for c, lab in enumerate(labels):
    msk = C == c
    print(f"{lab:12s} {msk.mean():6.3f} " + " ".join(f"{np.stack(v)[msk].sum() / npx * 1e3:8.3f}" for v in se.values()))
print(f"{'total MSE':12s} {'':6s} " + " ".join(f"{t / npx * 1e3:8.3f}" for t in tot.values()), "(x1e-3)")
print("PSNR", " ".join(f"{k} {-10*np.log10(t/npx):.2f}" for k, t in tot.items()))
