"""Probe (issue 15): does the history blur the texture because the driver accumulates
*radiance*?  WSKPN's driver blends the reprojected accumulated colour with the frame; every
reprojection resamples it bilinearly, so over a history the texture it holds is blurred, and the
model demodulates that blurred radiance by the current frame's sharp albedo.  SVGF accumulates
demodulated illumination instead.  This runs shipped models through the driver twice on one
data set: as shipped, and with the accumulation in irradiance (colour / (albedo + ALBEDO_EPS),
re-modulated by the frame's own albedo before the graph), no retraining.

    python docs/results/demod-history/probe.py DATA SPP WARMUP MODEL.onnx... > out.md
"""
import dataclasses
import sys

import numpy as np

from mcdenoise.runtime.inputs import ALBEDO_EPS
from mcdenoise.runtime.temporal import Protocol
from mcdenoise.training.methods import ONNXModel
from mcdenoise.training.scoring import run_methods
from mcdenoise.training.testsets import read_sequences


class DemodulatedProtocol(Protocol):
    """The driver's protocol with each accumulated input accumulated divided by the frame's
    albedo input + ALBEDO_EPS (the models' own demodulation) and multiplied back for the graph."""

    @staticmethod
    def _m(feeds):
        a = feeds["albedo"]
        return a + np.float32(ALBEDO_EPS)

    def start(self, feeds, like, spp=None):
        kept = super().start(feeds, like, spp)
        m = self._m(feeds)
        return {k: v / m for k, v in kept.items()}

    def follow(self, feeds, kept, motion, cur, prev, contiguous=lambda a: a, reproject_fn=None, spp=None, **kw):
        m = self._m(feeds)
        for _, inp, _, _ in self.accumulate:
            feeds[inp] = feeds[inp] / m
        out = super().follow(feeds, kept, motion, cur, prev, contiguous, reproject_fn, spp, **kw)
        for _, inp, _, _ in self.accumulate:
            feeds[inp] = contiguous(feeds[inp] * m)
        return out


def main():
    data, spp, warmup, models = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4:]
    methods = []
    for path in models:
        plain = ONNXModel(path)
        demod = ONNXModel(path)
        demod.denoiser.protocol = DemodulatedProtocol(**{f.name: getattr(demod.denoiser.protocol, f.name)
                                                         for f in dataclasses.fields(Protocol)})
        demod.name = plain.name + " (irradiance history)"
        methods += [plain, demod]
    res = run_methods(methods, read_sequences(data, False), spp, log=lambda m: None, warmup=warmup)
    print(f"`{data}`, {spp} spp, PSNR dB over all frames / after {warmup} warm-up frames, TRMAE and WTE after warm-up\n")
    print("| model | PSNR all | after warm-up | TRMAE | WTE |\n|---|---:|---:|---:|---:|")
    for name, r in res.items():
        a = r.get("after_warmup") or {}
        print(f"| {name} | {r['psnr']:.2f} | {a.get('psnr', float('nan')):.2f} | {a.get('trmae', float('nan')):.3f} | "
              f"{a.get('wte', float('nan')):.3f} |")


if __name__ == "__main__":
    main()
