"""Probe (issue 15): what a history can give before any network, and what it costs.

Two "methods" run through the driver's own reprojection and consistency test
(:func:`runtime.temporal.reproject`, the frame's true motion and guides), no model:

* ``accumulated input, alpha A``: the noisy colour blended with its reprojected history at the
  current frame's weight A (A = 1: the frame alone). What the WSKPN models see.
* ``accumulated reference, alpha A``: the *reference* blended the same way. Against the
  reference itself this is pure lag and resampling blur (each reprojection resamples the
  history bilinearly): the best any filter fed that history can do where it trusts it.
* ``warped previous reference``: alpha 0 for one frame only: frame t-1's reference warped onto
  frame t (disoccluded pixels take frame t's): the error of one reprojection, lag and blur of a
  single step.
* ``... (irradiance)``: the same, accumulated divided by the frame's albedo + ALBEDO_EPS and
  multiplied back by the current frame's (SVGF's demodulated history: the texture comes from
  the sharp current albedo, only the illumination is resampled).

    python docs/results/history-bound/probe.py DATA SPP WARMUP > out.md
"""
import sys

import numpy as np

from mcdenoise.runtime import temporal
from mcdenoise.runtime.inputs import ALBEDO_EPS
from mcdenoise.training.scoring import run_methods
from mcdenoise.training.testsets import read_sequences


def _nchw(a):
    return np.ascontiguousarray(a.transpose(2, 0, 1)[None], np.float32)


class Accumulated:
    def __init__(self, alpha: float, source: str, irradiance: bool = False):
        self.alpha, self.source, self.irradiance = alpha, source, irradiance
        self.name = (f"accumulated {'input' if source == 'color' else source}{' (irradiance)' if irradiance else ''}, "
                     f"alpha {alpha:g}")
        self.reset()

    def reset(self):
        self.acc, self.guides, self.prev = None, None, None

    def __call__(self, fr):
        cur = _nchw(getattr(fr, self.source))
        m = _nchw(fr.albedo) + np.float32(ALBEDO_EPS) if self.irradiance else np.float32(1.0)
        cur = cur / m
        guides = {"depth": _nchw(fr.depth), "position": _nchw(fr.position), "normal": _nchw(fr.normal)}
        if self.alpha == 0.0 and self.acc is not None:   # one step: the history is the previous frame alone
            self.acc = self.prev
        self.prev = cur
        if self.acc is None or self.alpha >= 1.0:
            self.acc = cur
        else:
            (self.acc,), _ = temporal.reproject([self.acc], _nchw(fr.motion), guides, self.guides,
                                                blend=[(cur, self.alpha)])
        self.guides = guides
        return (self.acc * m)[0].transpose(1, 2, 0)


def main():
    data, spp, warmup = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    methods = [Accumulated(a, s, irr) for s in ("color", "reference") for irr in (False, True)
               for a in (1.0, spp / (spp + 1.0), 0.2) if not (irr and a >= 1.0)]
    methods.append(Accumulated(0.0, "reference"))
    methods[-1].name = "warped previous reference"
    res = run_methods(methods, read_sequences(data, False), spp, log=lambda m: None, warmup=warmup)
    print(f"`{data}`, {spp} spp: PSNR dB against the reference over all frames / after {warmup} warm-up frames\n")
    print("| what | PSNR all | after warm-up |\n|---|---:|---:|")
    for name, r in res.items():
        if name == "accumulated reference, alpha 1":
            continue   # the reference itself
        a = r.get("after_warmup") or {}
        print(f"| {name} | {r['psnr']:.2f} | {a.get('psnr', float('nan')):.2f} |")


if __name__ == "__main__":
    main()
