"""Seconds per training step of SPEC (default wskpn-6; batch 8 of 8-frame windows, 64x64 crops,
spp 1-8 with one spp a batch, the temporal term), split into loading, forward and backward, on
data/curves-test: the number behind "train with nothing else running" in README.md.

    python docs/results/scale/step_time.py [SPEC]            # alone
    (renders running)  python docs/results/scale/step_time.py

2026-12-02, 2-vCPU AMD EPYC, 2 threads, after the first two steps: alone (renders paused with
pkill -STOP) forward + backward 0.6 s and, in a second run, 0.7-1.2 s; beside two nice-19
`mcdenoise render` processes 3-24 s forward and 3-26 s backward.
Later the same day, ``anf-s`` alone (kernel size 13): 3.1-12.7 s forward (1-8 spp) and 6-15 s
backward, 17-20 s a step: ANF's "16 s a step" of earlier sessions was its own cost, not
contention (the backward of 4 x 169 taps).
"""
import sys
import time

import torch

from mcdenoise.training.dataset import SequenceDataset, collate
from mcdenoise.training.models.common import OUTPUT
from mcdenoise.training.specs import build_model, load_spec
from mcdenoise.training.train import LOSSES, run_window, window_loss

torch.set_num_threads(2)
spec = load_spec(sys.argv[1] if len(sys.argv) > 1 else "wskpn-6")
model = build_model(spec)
ds = SequenceDataset("data/curves-test", "all", tuple(spec.inputs.layers), crop=64, spp_choices=[1, 2, 4, 8],
                     window=8, seed=0, sample_groups=tuple(g for g, _ in spec.inputs.sample_groups))
opt = torch.optim.Adam(model.parameters(), 1e-3)
for i in range(6):
    t0 = time.perf_counter()
    n = ds.batch_spp(i)      # one S a batch: per-sample models stack the sample axis
    b = collate([ds[j % len(ds), n] for j in range(i * 8, i * 8 + 8)])
    t1 = time.perf_counter()
    outs = run_window(model, b, spec.protocol)
    loss = window_loss(LOSSES["smape"], [o[OUTPUT] for o in outs], b["reference"], 0.25)
    t2 = time.perf_counter()
    opt.zero_grad()
    loss.backward()
    opt.step()
    print(f"{spec.name} step {i} ({n} spp): load {t1 - t0:.2f} s, forward {t2 - t1:.2f} s, backward {time.perf_counter() - t2:.2f} s")
