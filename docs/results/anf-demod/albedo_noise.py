"""How noisy is the albedo layer a demodulating model re-modulates by?  Per spp, the mean relative
difference between a frame's albedo layer at that spp and at the 8 stored samples (itself not
converged, so this understates the error), over all pixels and over textured ones (look.TEXTURE).
The samples are jittered anew every frame, so this error changes from frame to frame, and
re-modulation puts it straight into the output.

    python docs/results/anf-demod/albedo_noise.py --data data/long-slow > docs/results/anf-demod/albedo_noise.txt"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from mcdenoise.training.testsets import at_spp, read_sequences

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from look import textured  # noqa: E402  (this folder's one texture mask)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--frames", type=int, default=8, help="frames of each sequence read")
    a = p.parse_args()
    print(f"# {a.data}: albedo layer at spp vs at 8 spp, mean |difference| / (8-spp albedo + 0.01)")
    print("| spp | all pixels | textured pixels |")
    print("|---:|---:|---:|")
    rows = {s: [[], []] for s in (1, 2, 4)}
    for frames in read_sequences(a.data):
        for fr in frames[:a.frames]:
            full = at_spp(fr, 8).albedo.astype(np.float64)
            tex = textured(full)
            for s in rows:
                rel = (np.abs(at_spp(fr, s).albedo - full) / (full + 0.01)).mean(-1)
                rows[s][0].append(rel.mean())
                rows[s][1].append(rel[tex].mean())
    for s, (al, tx) in rows.items():
        print(f"| {s} | {np.mean(al):.3f} | {np.mean(tx):.3f} |")


if __name__ == "__main__":
    main()
