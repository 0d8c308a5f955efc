"""Probe (issue 15, section 1): are our references clean enough for what they measure, and what
would make them clean per unit of render time?

For the first frame of one sequence of a rendered set (its render arguments given after
``--``), render a near-converged image (TRUTH_SPP samples, seed stream 20) and K independent
chunks of CHUNK_SPP samples (streams 30..), then score against the near-converged image, in
ANF Eq. 14 PSNR:

* the set's stored reference (the mean of REF_SPP samples in one call);
* the plain mean of the K chunks (K x CHUNK_SPP samples);
* the median of means of the K chunks per pixel and channel (Buisine et al., "Firefly removal in
  Monte Carlo rendering with adaptive Median of meaNs", EGSR 2021): a robust estimate that drops
  the rare high-energy paths a few hundred samples cannot resolve, at the cost of bias there;
* the shipped models' and Open Image Denoise's outputs on the 1- and 4-spp input (no history):
  what the references are asked to measure.

    python docs/results/reference-noise/probe.py SEQUENCE_INDEX TRUTH_SPP K CHUNK_SPP -- RENDER_ARGS...
"""
import argparse
import os
import sys
import tempfile

import numpy as np

from mcdenoise.runtime.frames import frame_name, read_frame
from mcdenoise.training.metrics import psnr


def main():
    cut = sys.argv.index("--")
    index, truth_spp, k, chunk_spp = (int(v) for v in sys.argv[1:cut])
    from mcdenoise.training.render import command
    from mcdenoise.training.render.renderer import SequenceRenderer
    from mcdenoise.training.render.variant import choose_variant, init_mitsuba

    p = argparse.ArgumentParser()
    command.add_arguments(p)
    a = p.parse_args(sys.argv[cut + 1:])
    variant, _ = choose_variant(a.variant)
    mi = init_mitsuba(variant)
    job = command.plan(a)[index]
    stored = read_frame(os.path.join(a.out, job["name"], frame_name(0)), samples=True)
    with tempfile.TemporaryDirectory() as tmp:
        seq = command._sequence(mi, a, job, tmp)
        truth, _ = SequenceRenderer(mi, seq, spp=1, ref_spp=truth_spp, variant=variant).reference(0, stream=20)
        chunks = np.stack([SequenceRenderer(mi, seq, spp=1, ref_spp=chunk_spp, variant=variant).reference(0, stream=30 + i)[0]
                           for i in range(k)])
    print(f"`{a.out}` sequence {job['name']}, frame 0, {a.size[0]}x{a.size[1]}: PSNR dB (ANF Eq. 14) against "
          f"a {truth_spp}-spp image\n")
    print("| image | spp | PSNR dB |\n|---|---:|---:|")
    print(f"| stored reference (mean) | {a.ref_spp} | {psnr(stored.reference, truth):.2f} |")
    print(f"| mean of {k} chunks | {k * chunk_spp} | {psnr(chunks.mean(0), truth):.2f} |")
    print(f"| median of {k} chunk means | {k * chunk_spp} | {psnr(np.median(chunks, 0), truth):.2f} |")
    print(f"| relative energy of the median of means (sum / sum of truth) | | "
          f"{float(np.median(chunks, 0).sum() / truth.sum()):.4f} |")
    from mcdenoise.training.methods import load_method, shipped_models
    from mcdenoise.training.testsets import at_spp

    for spp in (1, 4):
        fr = at_spp(stored, spp)
        for name in [*shipped_models(), "oidn-high"]:
            m = load_method(name)
            out = m(fr)
            print(f"| {m.name} on {spp} spp: against truth / against the stored reference | {spp} | "
                  f"{psnr(out, truth):.2f} / {psnr(out, stored.reference):.2f} |")


if __name__ == "__main__":
    main()
