"""Seconds per training step of a spec on this machine, float32 against ``--autocast bf16``.

One batch as a scale sitting trains it (data/train-256, 64x64 crops, 8-frame windows, spp drawn
from 1 2 4 8, batch 8), the forward through the driver's arithmetic (``run_window``), the loss
and the backward; the two arithmetics alternate for REPEATS rounds after a warm-up, so a busy
machine slows both alike. Prints a table (median seconds, ratio) and the first loss of each.

    python docs/results/scale/autocast_time.py [SPEC] [REPEATS] > docs/results/scale/autocast_time.txt
"""
import platform
import statistics
import sys
import time

import torch

from mcdenoise.runtime.contract import OUTPUT
from mcdenoise.training.dataset import SequenceDataset, collate
from mcdenoise.training.specs import build_model, load_spec
from mcdenoise.training.train import LOSSES, run_window, window_loss

spec_name = sys.argv[1] if len(sys.argv) > 1 else "wskpn-6e"
repeats = int(sys.argv[2]) if len(sys.argv) > 2 else 6
spec = load_spec(spec_name)
ds = SequenceDataset("data/train-256", "train", spec.inputs.layers, crop=64, spp_choices=(1, 2, 4, 8), window=8,
                     max_sequences=2, sample_groups=tuple(g for g, _ in spec.inputs.sample_groups))
batch = {k: torch.as_tensor(v) for k, v in collate([ds[i] for i in range(8)]).items()}
torch.manual_seed(0)
model = build_model(spec)
model.train()


def step(bf16: bool) -> tuple[float, float]:
    t = time.perf_counter()
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
        outs = run_window(model, batch, spec.protocol)
    loss = window_loss(LOSSES[spec.train.loss], [o[OUTPUT].float() for o in outs], batch["reference"], 0.25)
    model.zero_grad(set_to_none=True)
    loss.backward()
    return time.perf_counter() - t, float(loss.detach())


first = {bf: step(bf)[1] for bf in (False, True)}     # warm-up (oneDNN picks its kernels)
times: dict[bool, list[float]] = {False: [], True: []}
for _ in range(repeats):
    for bf in (False, True):
        times[bf].append(step(bf)[0])
cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), platform.processor())
print(f"{spec_name}, batch 8 x 8 frames x 64x64, {torch.get_num_threads()} threads, torch {torch.__version__}, {cpu}")
print(f"median of {repeats} alternating steps (forward through run_window, loss, backward)\n")
print("| arithmetic | s / step | ratio | first loss |\n|---|---:|---:|---:|")
base = statistics.median(times[False])
for bf in (False, True):
    med = statistics.median(times[bf])
    print(f"| {'bf16 autocast' if bf else 'float32'} | {med:.3f} | {med / base:.2f} | {first[bf]:.5f} |")
