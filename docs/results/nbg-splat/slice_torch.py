"""Torch eager cost of the 2026-12-05 NBG slice rewrite: the shipped nbg-2l-1g and nbg-2l-3g,
whole deployed graph at 1280x720 on a synthetic frame, the slice before (inlined below, as at
06cff45) and after (training/models/nbg.py) interleaved in one process, 2 threads, medians of 6.

    python docs/results/nbg-splat/slice_torch.py
"""
import time

import numpy as np
import torch

import mcdenoise.training.models.nbg as nbg
from mcdenoise.export.onnx_export import load_exported
from mcdenoise.training.harness import synthetic_frame
new = nbg.slice_rows
def old(grid, index, weight, n, h, w, normalization="cell"):
    c = grid.shape[1] - 1
    wsum = grid[:, c:]
    occupied = (wsum > 0).to(grid.dtype)
    grid = torch.cat([grid[:, :c] * (occupied / wsum.clamp(min=1e-30)), occupied], dim=1)
    taps = grid.index_select(0, index).reshape(n, 8, -1, c + 1)
    acc = (taps * weight).sum(dim=1)
    out = acc[:, :, :c] / acc[:, :, c:].clamp(min=nbg.SLICE_FLOOR)
    return out.transpose(1, 2).reshape(n, c, h, w)
torch.set_num_threads(2)
W, H = 1280, 720
fr = synthetic_frame(W, H, 3)
def chw(a): a = np.asarray(a, np.float32); return torch.from_numpy((a.transpose(2,0,1) if a.ndim==3 else a[None])[None].copy())
base = {"color": chw(fr["color"]), "albedo": chw(fr["albedo"]), "normal": chw(fr["normal"]), "depth": chw(fr["depth"]),
        "prev_accum": chw(fr["color"]), "history": torch.ones((1,1,H,W)), "accum_weight": torch.full((1,1,1,1),0.2)}
for name in ("nbg-2l-1g", "nbg-2l-3g"):
    spec, model, _ = load_exported(f"models/{name}.onnx"); model = model.deploy()
    args = [base[k] for k in model.input_names]
    ts = {"old": [], "new": []}
    with torch.inference_mode():
        for i in range(6):
            for tag in (("old", "new") if i % 2 == 0 else ("new", "old")):
                nbg.slice_rows = old if tag == "old" else new
                t0 = time.perf_counter(); model(*args); ts[tag].append(1e3 * (time.perf_counter() - t0))
    print(name, "torch eager whole graph", {k: round(float(np.median(v)), 1) for k, v in ts.items()})
