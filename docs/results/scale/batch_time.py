"""Seconds to build a training batch on one core, against a CPU training step: the numbers behind
``train --loader-workers`` in README.md and gpu_train.sh's LOADER_WORKERS.

    python docs/results/scale/batch_time.py [DATA] > docs/results/scale/batch_time.txt

On DATA (default data/train-256, the sittings' shards; its first 4 training sequences): reading
the 32 frames with 1 and 2 processes (SequenceDataset.warm), then the median of 6 batches of
wskpn-6e's items built in this process for the GPU script's batch (16 items, 8 frames, 128x128,
with the firefly augmentation) and the CPU sittings' (8 items, 64x64), and the median of 4 CPU
training steps (2 threads) on the latter. Run it with nothing else on the machine.
"""
import sys
import time

import numpy as np
import torch

from mcdenoise.runtime.contract import OUTPUT
from mcdenoise.training.dataset import SequenceDataset, collate
from mcdenoise.training.specs import build_model, load_spec
from mcdenoise.training.train import LOSSES, run_window, window_loss

data = sys.argv[1] if len(sys.argv) > 1 else "data/train-256"
spec = load_spec("wskpn-6e")
layers = tuple(spec.inputs.layers)


def dataset(crop):
    return SequenceDataset(data, "train", layers, crop=crop, window=8, fireflies=0.001, max_sequences=4)


for processes in (1, 2):
    ds = dataset(64)
    t = time.perf_counter()
    n = ds.warm(processes)
    print(f"read {n} frames with {processes} process(es): {time.perf_counter() - t:.1f} s")
for bs, crop in ((16, 128), (8, 64)):
    ds = dataset(crop)
    ds.warm(2)
    ts = []
    for s in range(6):
        t = time.perf_counter()
        collate([ds[s * bs + j] for j in range(bs)])
        ts.append(time.perf_counter() - t)
    print(f"batch of {bs} items x 8 frames at {crop}x{crop}: median {np.median(ts):.3f} s on one core")
torch.set_num_threads(2)
model = build_model(spec)
opt = torch.optim.Adam(model.parameters(), spec.train.lr)
ts = []
for s in range(5):
    b = collate([ds[s * 8 + j] for j in range(8)])
    t = time.perf_counter()
    outs = run_window(model, b, spec.protocol)
    loss = window_loss(LOSSES[spec.train.loss], [o[OUTPUT] for o in outs], b["reference"], 0.25)
    opt.zero_grad()
    loss.backward()
    opt.step()
    if s:
        ts.append(time.perf_counter() - t)
print(f"CPU training step on that batch (2 threads, forward + backward + Adam): median {np.median(ts):.2f} s")
