"""The driver's per-frame temporal work as ONNX graphs: reprojection with the consistency test
and the accumulation, exported from the very torch functions the trainer runs
(:func:`runtime.temporal.reproject`, :func:`runtime.temporal.accumulate`), so that a device
provider (CUDA) runs it beside the model, on state that never leaves the device, while numpy
does it on the CPU.

    python -m mcdenoise.export.prelude --out models/driver   # regenerate the shipped files

One graph per count K of kept tensors (1 to :data:`runtime.prelude.MAX_SLOTS`; a model's state
tensors and accumulated inputs, each its own input, so a state output bound on the device is
fed back as it is): ``prelude-<K>.onnx``. Inputs (float32, NCHW, batch 1, dynamic C, H, W):
``prev<i>`` (1, C_i, H, W) kept tensor i (non-finite values read as 0: a state output kept on
the device is never checked on the host), ``current<i>`` (1, C_i, H, W) this frame's value of
an accumulated input (anything for model state), ``alpha`` (K,) the current frame's weight and
``blend`` (K,) 1 where tensor i is accumulated, 0 where it is model state; ``motion``
(1, 2, H, W); the guides ``cur_depth``, ``cur_position``, ``cur_normal``, ``prev_depth``,
``prev_position``, ``prev_normal``. Outputs: ``warped<i>`` (accumulated where ``blend`` is 1)
and ``history`` (1, 1, H, W). :class:`runtime.prelude.PreludeGraph` runs them with the
signature of ``reproject``.

The frame's input conversion, for the same providers (:meth:`runtime.prelude.PreludeGraph.convert`):
``convert.onnx`` takes one layer as the frame holds it, ``x`` (H, W, C) float32, with ``fill``
(1,) the value a non-finite one becomes, ``radiance`` (1,) 1 for a radiance layer (negatives
-> 0, values above MAX_RADIANCE clamped) and ``scale`` (1,) the exposure it is multiplied by
after; it gives ``planes`` (1, C, H, W) and ``counts`` (3,) int64, the non-finite, negative and
clamped values replaced: :func:`runtime.inputs.frame_planes`' arithmetic, tested equal to it.
``screen.onnx`` turns world normals ``normal`` (1, 3, H, W) into the camera's screen frame with
``axes`` (3, 3) (:func:`runtime.inputs.camera_axes`) as :func:`runtime.inputs.screen_normal_planes`.
``post.onnx`` gives the model's ``output`` (1, 3, H, W) back as ``image`` (H, W, 3) times
``scale`` (1,), with ``checks`` (2,) its minimum and sum (:meth:`runtime.prelude.PreludeGraph.post`).
"""
from __future__ import annotations

import argparse
from pathlib import Path

from mcdenoise.runtime.prelude import CONVERT_FILE, GUIDES, MAX_SLOTS, POST_FILE, SCREEN_FILE, SLOT_FILE, inputs, outputs

OPSET = 17


def _module(k: int):
    import torch

    from mcdenoise.runtime.temporal import accumulate, reproject

    class Prelude(torch.nn.Module):
        def forward(self, *args):
            prev = [torch.where(torch.isfinite(p), p, torch.zeros_like(p)) for p in args[:k]]
            current = args[k:2 * k]
            alpha, blend, motion = args[2 * k:2 * k + 3]
            g = dict(zip(GUIDES, args[2 * k + 3:]))
            cur = {n: g["cur_" + n] for n in ("depth", "position", "normal")}
            old = {n: g["prev_" + n] for n in ("depth", "position", "normal")}
            warped, history = reproject(prev, motion, cur, old)
            outs = [w + blend[i] * (accumulate(c, w, history, alpha[i]) - w)
                    for i, (w, c) in enumerate(zip(warped, current))]
            return (*outs, history)

    return Prelude()


def _convert_modules():
    import torch

    from mcdenoise.runtime.inputs import MAX_RADIANCE

    @torch.jit.script
    def sanitize(p: torch.Tensor, fill: torch.Tensor, radiance: torch.Tensor, top: float):
        # A frame is almost always clean: three reductions (the sum is non-finite if any value
        # is; onnxruntime's ReduceMin/Max need not propagate NaN) decide it, as in numpy, and a
        # clean layer skips the masks. On the CPU provider the masks took 100+ ms at 720p.
        lo, hi = p.min(), p.max()
        clean = bool(torch.isfinite(p.sum()) & ((radiance < 0.5) | ((lo >= 0.0) & (hi <= top))).all())
        if clean:
            return p, torch.zeros(3, dtype=torch.int64)
        finite = torch.isfinite(p)
        p = torch.where(finite, p, fill)
        is_radiance = radiance > 0.5
        neg = (p < 0.0) & is_radiance
        big = (p > top) & is_radiance
        p = torch.where(neg, torch.zeros_like(p), torch.where(big, torch.full_like(p, top), p))
        return p, torch.stack([(~finite).sum(), neg.sum(), big.sum()]).to(torch.int64)

    class Convert(torch.nn.Module):
        def forward(self, x, fill, radiance, scale):
            p, counts = sanitize(x.permute(2, 0, 1).unsqueeze(0), fill, radiance, MAX_RADIANCE)
            return p * scale, counts

    class Screen(torch.nn.Module):
        def forward(self, normal, axes):
            # the numpy path's order of products and sums (runtime.inputs.screen_normal_planes)
            return torch.cat([normal[:, 0:1] * axes[i, 0] + normal[:, 1:2] * axes[i, 1] + normal[:, 2:3] * axes[i, 2]
                              for i in range(3)], dim=1)

    class Post(torch.nn.Module):
        def forward(self, output, scale):
            o = output[0]
            return o.permute(1, 2, 0) * scale, torch.stack([o.min(), o.sum()])

    return Convert(), Screen(), Post()


def export_convert(out_dir: str | Path) -> list[Path]:
    """Write ``convert.onnx`` and ``screen.onnx`` (module docstring) into ``out_dir``."""
    import numpy as np
    import torch

    convert, screen, post = _convert_modules()
    rng = np.random.default_rng(0)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    one = torch.ones(1)
    x = torch.from_numpy(rng.random((6, 5, 3), dtype=np.float32))
    paths = [out_dir / CONVERT_FILE, out_dir / SCREEN_FILE, out_dir / POST_FILE]
    torch.onnx.export(convert, (x, one, one, one), str(paths[0]), input_names=["x", "fill", "radiance", "scale"],
                      output_names=["planes", "counts"], dynamic_axes={"x": {0: "H", 1: "W", 2: "C"},
                                                                     "planes": {1: "C", 2: "H", 3: "W"}},
                      opset_version=OPSET, dynamo=False)
    torch.onnx.export(screen, (x.permute(2, 0, 1)[None], torch.eye(3)), str(paths[1]), input_names=["normal", "axes"],
                      output_names=["screen"], dynamic_axes={"normal": {2: "H", 3: "W"}, "screen": {2: "H", 3: "W"}},
                      opset_version=OPSET, dynamo=False)
    torch.onnx.export(post, (x.permute(2, 0, 1)[None], one), str(paths[2]), input_names=["output", "scale"],
                      output_names=["image", "checks"], dynamic_axes={"output": {2: "H", 3: "W"}, "image": {0: "H", 1: "W"}},
                      opset_version=OPSET, dynamo=False)
    return paths


def example(k: int = 2, h: int = 24, w: int = 32, seed: int = 0, channels=None) -> dict:
    """Plausible inputs of the K-slot graph: a slanted plane seen from a camera that moved
    (sub-pixel motion, some taps off-screen), depth misses here and there; ``channels`` per
    slot (default 3, 1, 4, 2, ...)."""
    import numpy as np

    rng = np.random.default_rng(seed)
    chans = list(channels) if channels is not None else [(3, 1, 4, 2)[i % 4] for i in range(k)]
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    depth = (5 + 0.05 * xs + 0.02 * ys)[None, None]
    depth[..., rng.random((h, w)) < 0.03] = 0.0
    pos = np.stack([xs * 0.1, ys * 0.1, depth[0, 0]])[None].astype(np.float32)
    nrm = np.zeros((1, 3, h, w), np.float32)
    nrm[:, 2] = -1
    motion = np.stack([np.full((h, w), 0.37), np.full((h, w), -0.21)])[None].astype(np.float32)
    feeds = {**{f"prev{i}": rng.random((1, c, h, w), dtype=np.float32) * 2 for i, c in enumerate(chans)},
             **{f"current{i}": rng.random((1, c, h, w), dtype=np.float32) for i, c in enumerate(chans)},
             "alpha": np.full(k, 0.2, np.float32), "blend": (np.arange(k) % 2).astype(np.float32),
             "motion": motion, "cur_depth": depth.astype(np.float32), "cur_position": pos, "cur_normal": nrm,
             "prev_depth": depth.astype(np.float32), "prev_position": pos + np.float32(0.01), "prev_normal": nrm.copy()}
    return feeds


def export(out_dir: str | Path, k: int) -> Path:
    """Write the K-slot prelude graph into ``out_dir`` (TorchScript exporter, opset 17, dynamic
    C_i/H/W)."""
    import torch

    out = Path(out_dir) / SLOT_FILE.format(k)
    out.parent.mkdir(parents=True, exist_ok=True)
    feeds = example(k)
    names_in, names_out = inputs(k), outputs(k)
    args = tuple(torch.from_numpy(feeds[n]) for n in names_in)
    axes = {n: ({1: f"C{n[-1]}", 2: "H", 3: "W"} if n[:-1] in ("prev", "current", "warped") else
                {} if n in ("alpha", "blend") else {2: "H", 3: "W"}) for n in (*names_in, *names_out)}
    torch.onnx.export(_module(k), args, str(out), input_names=list(names_in), output_names=list(names_out),
                      dynamic_axes=axes, opset_version=OPSET, dynamo=False)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m mcdenoise.export.prelude", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="folder to write prelude-1.onnx ... prelude-K.onnx into")
    a = p.parse_args(argv)
    for k in range(1, MAX_SLOTS + 1):
        print(f"wrote {export(a.out, k)}")
    for path in export_convert(a.out):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
