"""The driver's per-frame temporal work as one ONNX graph: reprojection with the consistency
test and the accumulation, exported from the very torch functions the trainer runs
(:func:`runtime.temporal.reproject`, :func:`runtime.temporal.accumulate`), so that a
device provider (CUDA) can run it beside the model while numpy does it on the CPU.

    python -m mcdenoise.export.prelude --out models/driver/prelude.onnx   # regenerate the shipped file

Graph inputs (float32, NCHW, batch 1, dynamic C, H, W): ``prev`` (1, C, H, W) the kept
history (state channels and accumulated inputs stacked), ``current`` (1, C, H, W) this frame's
values of the accumulated channels (anything for the others), ``alpha`` (1, C, 1, 1) the
current frame's weight per channel, ``blend`` (1, C, 1, 1) 1 where a channel is accumulated,
0 where it is model state; ``motion`` (1, 2, H, W); the guides ``cur_depth``,
``cur_position``, ``cur_normal``, ``prev_depth``, ``prev_position``, ``prev_normal``. Outputs:
``warped`` (1, C, H, W) (accumulated where ``blend`` is 1) and ``history`` (1, 1, H, W).
:class:`runtime.prelude.PreludeGraph` runs it with the signature of ``reproject``.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from mcdenoise.runtime.prelude import INPUTS, OUTPUTS

OPSET = 17


def _module():
    import torch

    from mcdenoise.runtime.temporal import accumulate, reproject

    class Prelude(torch.nn.Module):
        def forward(self, prev, current, alpha, blend, motion, cur_depth, cur_position, cur_normal,
                    prev_depth, prev_position, prev_normal):
            cur = {"depth": cur_depth, "position": cur_position, "normal": cur_normal}
            old = {"depth": prev_depth, "position": prev_position, "normal": prev_normal}
            (warped,), history = reproject([prev], motion, cur, old)
            acc = accumulate(current, warped, history, alpha)
            return warped + blend * (acc - warped), history

    return Prelude()


def example(c: int = 4, h: int = 24, w: int = 32, seed: int = 0) -> dict:
    """Plausible inputs: a slanted plane seen from a camera that moved (sub-pixel motion,
    some taps off-screen), depth misses here and there."""
    import numpy as np

    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    depth = (5 + 0.05 * xs + 0.02 * ys)[None, None]
    depth[..., rng.random((h, w)) < 0.03] = 0.0
    pos = np.stack([xs * 0.1, ys * 0.1, depth[0, 0]])[None].astype(np.float32)
    nrm = np.zeros((1, 3, h, w), np.float32)
    nrm[:, 2] = -1
    motion = np.stack([np.full((h, w), 0.37), np.full((h, w), -0.21)])[None].astype(np.float32)
    feeds = {"prev": rng.random((1, c, h, w), dtype=np.float32) * 2, "current": rng.random((1, c, h, w), dtype=np.float32),
             "alpha": np.full((1, c, 1, 1), 0.2, np.float32),
             "blend": (np.arange(c) % 2).astype(np.float32).reshape(1, c, 1, 1),
             "motion": motion, "cur_depth": depth.astype(np.float32), "cur_position": pos, "cur_normal": nrm,
             "prev_depth": depth.astype(np.float32), "prev_position": pos + np.float32(0.01), "prev_normal": nrm.copy()}
    return feeds


def export(out: str | Path) -> Path:
    """Write the prelude graph to ``out`` (TorchScript exporter, opset 17, dynamic C/H/W)."""
    import torch

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    feeds = example()
    args = tuple(torch.from_numpy(feeds[n]) for n in INPUTS)
    axes = {n: ({1: "C", 2: "H", 3: "W"} if n in ("prev", "current", "warped") else
                {1: "C"} if n in ("alpha", "blend") else {2: "H", 3: "W"}) for n in (*INPUTS, *OUTPUTS)}
    torch.onnx.export(_module(), args, str(out), input_names=list(INPUTS), output_names=list(OUTPUTS),
                      dynamic_axes=axes, opset_version=OPSET, dynamo=False)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m mcdenoise.export.prelude", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="ONNX file to write")
    a = p.parse_args(argv)
    print(f"wrote {export(a.out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
