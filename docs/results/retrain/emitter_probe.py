"""Where the relMSE outliers come from: per frame of data/curves-test at 1 spp, each model's
relMSE, its worst pixel (reference, output, noisy input there) and the output/reference mean
ratio; then the neighbourhood of the retrained model's worst pixel (albedo, colour, the
demodulated irradiance colour / (albedo + ALBEDO_EPS), the reference, the emissive flag).

    mcdenoise export docs/results/retrain/run --out /tmp/wskpn-6-r2.onnx
    python docs/results/retrain/emitter_probe.py /tmp/wskpn-6-r2.onnx models/wskpn-6.onnx
"""
import sys

import numpy as np

from mcdenoise.runtime.inputs import ALBEDO_EPS
from mcdenoise.training.evaluate import read_sequences
from mcdenoise.training.methods import load_method
from mcdenoise.training.metrics import RELMSE_EPS
from mcdenoise.training.testsets import at_spp

seqs = read_sequences("data/curves-test", False)
worst = None
for path in sys.argv[1:]:
    m = load_method(path, threads=2)
    rows = []
    for si, frames in enumerate(seqs):
        m.reset()
        for t, fr in enumerate(frames):
            f = at_spp(fr, 1)
            out, ref = m(f), f.reference
            e = (out - ref) ** 2 / (ref ** 2 + RELMSE_EPS)
            y, x = np.unravel_index(np.argmax(e.max(-1)), e.shape[:2])
            rows.append((float(e.mean()), si, t, int(y), int(x), float(ref[y, x].mean()), float(out[y, x].mean()),
                         float(f.color[y, x].mean()), float(out.mean() / ref.mean())))
    rows.sort(reverse=True)
    print(f"{path}: mean relMSE {np.mean([r[0] for r in rows]):.2f}")
    for r in rows[:5]:
        print("  relMSE %.1f  seq %d frame %d  worst pixel (%d, %d): reference %.3f output %.2f noisy %.3f;"
              "  output/reference mean %.3f" % r)
    worst = worst or rows[0]
_, si, t, y, x = worst[:5]
f = at_spp(seqs[si][t], 1)
sl = (slice(max(0, y - 1), y + 3), slice(max(0, x - 4), x + 5))
np.set_printoptions(precision=3, suppress=True, linewidth=160)
print(f"around seq {si} frame {t} pixel ({y}, {x}):")
for name, v in (("albedo", f.albedo), ("colour", f.color), ("irradiance", f.color / (f.albedo + ALBEDO_EPS)),
                ("reference", f.reference), ("emissive", f.sample_feature("emissive").mean(0))):
    print(f"{name}\n{v[sl].mean(-1)}")
