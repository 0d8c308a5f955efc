"""``mcdenoise train SPEC --data DIR --out RUN``: train a model spec into a run folder.

Training unrolls each item's window of T frames exactly as the runtime driver runs a
sequence: frame 0 starts with empty state (history 0); frame t>0 receives the model's
``next_*`` outputs of frame t-1 warped by :func:`runtime.temporal.reproject` (the same
function the driver uses) with the consistency-test history mask, and each input of the
spec's ``[[accumulate]]`` as its accumulation (:func:`runtime.temporal.accumulate` of the
frame's value and the previous accumulation warped the same way).  The loss (spec
``train.loss``) is averaged over the T frames.

Resume is exact: item order is a pure function of (seed, epoch, index), and the checkpoint
stores model, optimiser, epoch and position within the epoch.

Weight averaging (``--ema DECAY``, off by default): the run also keeps an exponential moving
average of the weights (:func:`ema_update`), which validation scores and export ships; the
live weights stay what the optimiser steps and what resume continues from. Why: at a constant
rate the learning curves' test PSNR moved 0.5-1 dB between evaluations of one run
(docs/results/curves), so the last weights of a run are a draw from that spread; their
average is not.

Several processes (``torchrun --nproc_per_node N -m mcdenoise.runtime.cli train ...``, on one
machine or several): torch's DistributedDataParallel, gloo on the CPU, NCCL on GPUs. Every
process builds the same model and walks the same item order; step k's global batch of
``batch_size`` items is split between them (``batch_size`` a multiple of N), DDP averages
the gradients, so a step equals one process's step on the whole batch (BatchNorm aside: on
GPUs it becomes SyncBatchNorm; on the CPU, which has none, each process normalises its own
share). Process 0 alone validates and writes the run folder; the time budget and a
diverging loss stop every process at the same step.
"""
from __future__ import annotations

import copy
import gc
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from mcdenoise.runtime.args import CommandError, add_data, add_seed, add_threads
from mcdenoise.runtime.contract import OUTPUT
from mcdenoise.runtime.inputs import exposure_scale, sample_channels
from mcdenoise.training.dataset import CACHE_DTYPES, CACHE_MEMORY_FRACTION, SequenceDataset
from mcdenoise.training.metrics import psnr, relmse, smape
from mcdenoise.runtime.temporal import Protocol
from mcdenoise.runtime.transfer import gamma
from mcdenoise.training import runs


class TrainingDiverged(CommandError, FloatingPointError):
    """The loss became NaN or infinite; the run folder keeps its last checkpoint."""


def _l1_gamma(pred, ref):
    return (gamma(pred) - gamma(ref)).abs().mean()


def _l1_gamma_differences(out, out_prev, ref, ref_prev):
    """The temporal term of :func:`_l1_gamma`: frame differences taken *after* gamma. Why: gamma
    clips below 0, so the gamma of a linear difference dropped every darkening and charged a
    brightening through gamma's unbounded slope at 0 (five times the in-domain cost for a 25%
    step); the NBG fine-tunes of docs/results/nbg-retrain trained with that term."""
    return ((gamma(out) - gamma(out_prev)) - (gamma(ref) - gamma(ref_prev))).abs().mean()


_l1_gamma.frame_differences = _l1_gamma_differences


def _l1(pred, ref):
    return (pred - ref).abs().mean()


#: Loss name (spec ``train.loss``) -> function(pred, ref) on linear HDR NCHW tensors.
LOSSES = {"smape": smape, "l1": _l1, "l1_gamma": _l1_gamma}


#: Side in pixels of the blocks whose means the coarse term compares (``train --coarse-weight``).
COARSE_BLOCK = 8


def coarse(x, block: int = COARSE_BLOCK):
    """Means of ``x`` (B, C, H, W) over ``block`` x ``block`` blocks (a remainder dropped):
    (B, C, H // block, W // block)."""
    import torch.nn.functional as F

    return F.avg_pool2d(x, block)


def window_loss(loss_fn, outs: list, refs, temporal_weight: float = 0.0, coarse_weight: float = 0.0):
    """The training loss of a batch of windows: ``loss_fn`` of each frame's output against its
    reference, averaged over the T frames, plus ``temporal_weight`` times the same loss of the
    frame differences (output_t − output_t−1 against reference_t − reference_t−1, averaged over
    the T − 1 pairs; ANF §4's temporal term), which penalises flicker the per-frame term
    cannot see (a loss with a ``frame_differences(out, out_prev, ref, ref_prev)`` attribute
    compares the differences its own way: :func:`_l1_gamma_differences`), plus
    ``coarse_weight`` times the same loss of :data:`COARSE_BLOCK`-pixel block means of each
    frame (ours, issue 15). Why: the wskpn-6e runs come out 4-10% darker than the
    reference on the held-out lamp_occluder scene, where the noisy input is not (0.999), and most
    of their gap to Open Image Denoise is at scales of 8 pixels and more
    (docs/results/long/error_probe.txt). A per-pixel relative loss is least, where a pixel's true
    value is uncertain and skewed, for an estimate below its mean; a block's mean is far less
    uncertain, so its term asks for the energy back.
    outs: T tensors (B, 3, H, W); refs: (B, T, 3, H, W)."""
    loss = sum(loss_fn(o, refs[:, t]) for t, o in enumerate(outs)) / len(outs)
    if temporal_weight and len(outs) > 1:
        diff = getattr(loss_fn, "frame_differences", None) or (lambda o, op, r, rp: loss_fn(o - op, r - rp))
        loss = loss + temporal_weight * sum(diff(outs[t], outs[t - 1], refs[:, t], refs[:, t - 1])
                                            for t in range(1, len(outs))) / (len(outs) - 1)
    if coarse_weight:
        loss = loss + coarse_weight * sum(loss_fn(coarse(o), coarse(refs[:, t])) for t, o in enumerate(outs)) / len(outs)
    return loss


#: Key of an output dict of :func:`run_window` holding the model's regulariser of that frame.
REGULARIZER = "regularizer"


def run_window(model, batch: dict, protocol: Protocol, autoexposure: bool = True, forward=None):
    """Run the model over a batch of windows (B, T, C, H, W); returns a list of output dicts.

    The history is kept and fed back by ``protocol`` (:class:`runtime.temporal.Protocol`, the
    driver's own): zero state at each window's first frame, then the model's state outputs
    and the accumulated inputs reprojected frame to frame, differentiably.

    As the runtime driver does, each window's colour is scaled by its auto-exposure factor
    (:func:`runtime.inputs.exposure_scale` of its first frame, fixed for the window) and the
    ``output`` scaled back, so outputs are in the data's units and the state in the
    window's exposed units. ``forward``: what runs the model (default ``model``; the trainer
    passes its DistributedDataParallel wrapper).

    A per-sample model's ``samples`` (B, T, S, F, H, W) get the same exposure on their radiance
    channels; its settings are fed at their defaults; a model with a ``regularizer`` (ANF's
    Eq. 13) leaves each frame's in the output dict under :data:`REGULARIZER`."""
    import torch

    t_len = batch["color"].shape[1]
    groups = [g for g, _ in getattr(model, "sample_groups", ())]
    gain = None
    if groups and autoexposure:
        radiance = torch.zeros(batch["samples"].shape[3], dtype=batch["color"].dtype, device=batch["color"].device)
        radiance[sample_channels(groups, "radiance")] = 1
        gain = radiance.reshape(1, 1, -1, 1, 1)
    outputs = []
    kept, prev_guides = None, None
    exposure = exposure_scale(batch["color"][:, 0]) if autoexposure else None
    for t in range(t_len):
        feeds = {k: v[:, t] for k, v in batch.items() if k != "spp"}   # pixel inputs carry their layer's name
        if exposure is not None:
            feeds["color"] = feeds["color"] * exposure
            if gain is not None:
                feeds["samples"] = feeds["samples"] * (1 + (exposure[:, None] - 1) * gain)
        for name, value in getattr(model, "settings", {}).items():
            feeds[name] = torch.tensor(value)
        guides = {"depth": feeds["depth"], "position": feeds["position"], "normal": feeds["normal_world"]}
        if kept is None:
            acc = protocol.start(feeds, feeds["color"], spp=batch.get("spp"))
        else:
            acc = protocol.follow(feeds, kept, feeds["motion"], guides, prev_guides, spp=batch.get("spp"))
        missing = [n for n in model.input_names if n not in feeds]
        if missing:
            raise KeyError(f"model input(s) {missing} not in the batch ({sorted(feeds)})")
        out = dict(zip(model.output_names, (forward or model)(*[feeds[n] for n in model.input_names])))
        kept = protocol.update(acc, out)
        if getattr(model, "regularizer", None) is not None and model.training:
            out[REGULARIZER] = model.regularizer
        if exposure is not None:
            out[OUTPUT] = out[OUTPUT] / exposure
        outputs.append(out)
        prev_guides = guides
    return outputs


def evaluate(model, dataset, protocol: Protocol, batch_size: int = 4, device: str = "cpu") -> dict:
    """Validation metrics on the last frame of every window (temporal state warmed up):
    SMAPE, relMSE, PSNR (ANF Eq. 14) of the output and of the noisy input."""
    import torch

    from mcdenoise.training.dataset import collate

    model.eval()
    preds, refs, noisy = [], [], []
    with torch.no_grad():
        for i in range(0, len(dataset), batch_size):
            batch = collate([dataset[j] for j in range(i, min(len(dataset), i + batch_size))])
            batch = {k: v.to(device) for k, v in batch.items()}
            outs = run_window(model, batch, protocol)
            preds.append(outs[-1]["output"].cpu().numpy())
            refs.append(batch["reference"][:, -1].cpu().numpy())
            noisy.append(batch["color"][:, -1].cpu().numpy())
    model.train()
    p, r, n = (np.concatenate(a).transpose(0, 2, 3, 1) for a in (preds, refs, noisy))
    return {"val_smape": smape(p, r), "val_relmse": relmse(p, r), "val_psnr": psnr(p, r),
            "noisy_psnr": psnr(n, r), "noisy_smape": smape(n, r), "val_items": int(len(p))}


#: Suffixes of a BatchNorm layer's state_dict entries that hold its population statistics.
BN_STATS = ("running_mean", "running_var", "num_batches_tracked")
#: The epoch whose items (and the next ones') calibrate BatchNorm statistics (:func:`precise_bn`):
#: far beyond any run's epochs, so they are not the items of the steps just taken.
CALIBRATION_EPOCH = 10 ** 6
#: Training windows a new run calibrates BatchNorm on (``--precise-bn``): about 30 batches'
#: forward passes, a few seconds to a minute on a CPU; on mr-e sitting 4's weights 64 and 256
#: windows scored within 0.02 dB of each other.
PRECISE_BN_WINDOWS = 256


def precise_bn(model, dataset, protocol: Protocol, windows: int, batch_size: int, device: str = "cpu"):
    """A copy of ``model`` (eval mode) whose BatchNorm layers hold population statistics:
    the cumulative mean of the batch statistics over ``windows`` items of ``dataset`` (a
    training set: random crops, spp and symmetries), each item's frames unrolled as in
    training. The items are those of epochs :data:`CALIBRATION_EPOCH` and on, so every
    calibration of a run reads the same ones, whatever epoch training is at; the dataset's
    own epoch is restored.

    Why: at BatchNorm's default momentum of 0.1 the running statistics average the last ~10
    forward calls, and an 8-frame window makes 8 calls a step, so a run's saved statistics
    were those of its last one or two batches. After mr-e sitting 4 the first layer's running
    variance was 12-23x sitting 3's, and putting sitting 3's statistics back into that one
    layer alone gave +1.1 dB on curves-test (docs/results/scale, "mr-e sitting 4"). Returns
    ``model`` itself where it has no BatchNorm or ``windows`` is 0."""
    import torch
    from torch.nn.modules.batchnorm import _BatchNorm

    from mcdenoise.training.dataset import collate

    if not windows or not any(isinstance(m, _BatchNorm) for m in model.modules()):
        return model
    net = copy.deepcopy(model)
    net.train()
    for m in net.modules():
        if isinstance(m, _BatchNorm):
            m.reset_running_stats()
            m.momentum = None       # None: a cumulative average over every forward call
    epoch = dataset.epoch

    def item(k):
        dataset.set_epoch(CALIBRATION_EPOCH + k // len(dataset))
        return dataset[k % len(dataset)]

    try:
        with torch.no_grad():
            for i in range(0, windows, batch_size):
                batch = collate([item(k) for k in range(i, min(windows, i + batch_size))])
                run_window(net, {k: v.to(device) for k, v in batch.items()}, protocol)
    finally:
        dataset.set_epoch(epoch)
    for m in net.modules():
        if isinstance(m, _BatchNorm):
            m.momentum = 0.1
    return net.eval()


def add_arguments(p):
    p.add_argument("spec", help="model spec name (models_spec/<name>.toml) or path")
    add_data(p)
    p.add_argument("--out", required=True, metavar="RUN", help="run folder to create or resume")
    p.add_argument("--minutes", type=float, default=None, help="wall-clock budget (default: spec)")
    p.add_argument("--steps", type=int, default=None, help="optimiser steps (default: spec)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out exactly")
    p.add_argument("--init", default=None, metavar="RUN",
                   help="start a new run from RUN's weights and optimiser state (its spec, or another spec "
                        "of the same type whose weights fit, e.g. anf-s -> anf-sd), e.g. to continue training "
                        "on shards rendered in a later sitting; its steps count from 0. RUN may also be an "
                        "exported .onnx file (a shipped model, to fine-tune it on your own renders): its weights "
                        "only, Adam starts afresh; files whose export folded batch norm into the convolutions "
                        "(WSKPN) cannot be read back and need their run folder")
    p.add_argument("--batch-size", type=int, default=None)
    p.add_argument("--crop", type=int, default=None)
    p.add_argument("--window", type=int, default=None,
                   help="consecutive frames per training item, unrolled with the history (default: spec)")
    p.add_argument("--spp", type=int, nargs="+", default=None,
                   help="input samples per pixel drawn per item, e.g. 1 2 4 8 (default: spec)")
    p.add_argument("--fireflies", type=float, default=0.0, metavar="PER_PIXEL",
                   help="firefly augmentation: mean outlier samples per pixel per training frame, at "
                        "50-1000x the crop's reference mean, the reference unchanged (training.dataset; "
                        "the stress test's 1e-3 is a good start; default 0: none)")
    p.add_argument("--autocast", choices=("bf16",), default=None,
                   help="bf16: run the model's convolutions and matrix products in bfloat16 (torch.autocast; "
                        "faster on GPUs and on CPUs with AMX: docs/results/scale/autocast_time.txt); the loss, "
                        "WSKPN's kernel fusion and every validation stay float32. Default off; a resumed run "
                        "keeps the run's choice")
    p.add_argument("--cache-dtype", choices=("auto",) + CACHE_DTYPES, default="auto",
                   help="precision of the training frames' samples held in memory: float32 (exact), float16 "
                        "(half the memory; rounded to 11 significant bits); auto (default): float32 when it "
                        f"fits in {CACHE_MEMORY_FRACTION * 100:.0f}%% of the available memory, else float16, else a clear error. The run "
                        "records the choice and a resumed run keeps it")
    p.add_argument("--cache-dir", default=None, metavar="DIR",
                   help="keep the decoded training frames as .npy files in DIR, read back memory-mapped: "
                        "frames beyond the memory are read from disk instead of ending the run, and a later run "
                        "on the same frames (the next sitting, an A/B's other arm) decodes no EXR. The items "
                        "are the same; a pixel model's 256x256 frame at 8 spp takes 31 MB of disk in float32, 17 in float16. Not part of the run's "
                        "config: a resumed run may use another folder or none")
    p.add_argument("--max-sequences", type=int, default=None,
                   help="train on the first N sequences of the training split (by scene seed; nested subsets "
                        "for learning curves)")
    p.add_argument("--test", default=None, metavar="DIR",
                   help="also score every validation on this held-out folder of sequences (test_* metrics)")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="where the model trains (cuda: a GPU; with torchrun, one per process)")
    p.add_argument("--temporal-weight", type=float, default=None,
                   help="weight of the loss of frame differences (ANF §4: 0.25; default: spec)")
    p.add_argument("--coarse-weight", type=float, default=None,
                   help=f"weight of the loss of {COARSE_BLOCK}x{COARSE_BLOCK} block means of each frame, which "
                        "asks a model to keep the image's energy where a per-pixel relative loss lets it darken "
                        "uncertain pixels (default 0; a resumed run keeps its own)")
    p.add_argument("--lr", type=float, default=None,
                   help="peak learning rate (default: the spec's); e.g. a lower one to settle the weights "
                        "of a run started with --init, whose schedule starts again at its top")
    p.add_argument("--lr-schedule", choices=sorted(LR_SCHEDULES), default=None,
                   help="learning rate over the steps: constant (default), or cosine from the run's "
                        "lr (--lr, else the spec's) down to 1/20 of it at --steps (needs a finite --steps; a --minutes budget "
                        "that stops first leaves it part way)")
    p.add_argument("--clip-grad", type=float, default=None, metavar="NORM",
                   help="scale each step's gradient down to this global L2 norm where it is larger "
                        "(torch.nn.utils.clip_grad_norm_), so one batch with an outlier cannot undo a "
                        "sitting's training; each validation row records the interval's gradient norms "
                        "(grad_norm_median, grad_norm_max, clipped) either way. Default off; a resumed run "
                        "keeps its own")
    p.add_argument("--precise-bn", type=int, default=None, metavar="WINDOWS",
                   help="before each validation and the final save, BatchNorm's statistics are estimated "
                        "afresh over this many training windows (precise_bn), which validation scores and export "
                        f"ships; the live weights train as without it (default {PRECISE_BN_WINDOWS} for a new run; 0: off, "
                        "BatchNorm's running averages of the last few batches; a resumed run keeps its own)")
    p.add_argument("--ema", type=float, default=None, metavar="DECAY",
                   help="also keep a moving average of the weights (e.g. 0.995), which validation scores "
                        "and export ships (default: off)")
    p.add_argument("--loader-workers", type=int, default=0, metavar="N",
                   help="processes that build the next batches while the model trains (the run is the same "
                        "with any N; on a GPU machine give most of its cores; default 0: in this process)")
    p.add_argument("--val-fraction", type=float, default=0.2,
                   help="fraction of scene seeds held out for validation")
    p.add_argument("--val-every", type=int, default=0, help="validate every N steps (0: each epoch)")
    add_seed(p, "initial weights, crops, sample subsets, symmetries and the order of examples")
    add_threads(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def batch_share(order: list[int], pos: int, batch_size: int, rank: int, world: int) -> list[int]:
    """The items process ``rank`` of ``world`` trains on at step ``pos`` of an epoch whose item
    order is ``order``: its equal share of the global batch order[pos·B : (pos+1)·B]."""
    return order[pos * batch_size:(pos + 1) * batch_size][rank::world]


class EpochBatches:
    """The batches of one epoch from step ``start`` on, as a map-style data set: entry j is
    step ``start + j``'s collated batch (this process's share). A torch DataLoader's worker
    processes build them ahead of the step; each is a pure function of (seed, epoch, step),
    so the batches, and the run, are the ones the loop builds itself without workers."""

    def __init__(self, data, order: list[int], start: int, stop: int, batch_size: int, rank: int,
                 world: int, per_sample: bool):
        self.data, self.order, self.start, self.stop = data, order, start, stop
        self.batch_size, self.rank, self.world, self.per_sample = batch_size, rank, world, per_sample

    def __len__(self) -> int:
        return max(0, self.stop - self.start)

    def __getitem__(self, j: int) -> dict:
        from mcdenoise.training.dataset import collate

        pos = self.start + j
        # A per-sample model's batch shares one S (it stacks samples); pixel models draw per item.
        spp_now = self.data.batch_spp(pos) if self.per_sample else None
        return collate([self.data[i, spp_now] for i in batch_share(self.order, pos, self.batch_size, self.rank, self.world)])


def epoch_batches(batches: EpochBatches, workers: int = 0, pin: bool = False):
    """Iterate ``batches`` in order: in this process (``workers`` 0), or built ahead by that
    many forked processes (two batches each in flight). Why: a step of wskpn-6e on a GPU takes
    a fraction of the time one core needs to cut, subsample and transform its 8-frame items
    (0.88 s for 16 items of 128x128 here: docs/results/scale/batch_time.py), so without workers a GPU mostly waits for data."""
    if workers <= 0:
        return (batches[j] for j in range(len(batches)))
    import multiprocessing

    import torch

    # fork: the workers share the parent's cached frames (SequenceDataset.warm) copy-on-write
    ctx = multiprocessing.get_context("fork") if "fork" in multiprocessing.get_all_start_methods() else None
    return iter(torch.utils.data.DataLoader(batches, batch_size=None, shuffle=False, num_workers=workers,
                                            prefetch_factor=2, pin_memory=pin, multiprocessing_context=ctx))


def _distributed(device: str = "cpu") -> tuple[int, int]:
    """(rank, world size): from torchrun's environment, with the process group set up
    (gloo on the CPU, NCCL on CUDA); (0, 1) when not launched by torchrun."""
    import torch.distributed as dist

    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return 0, 1
    if not dist.is_initialized():
        dist.init_process_group("nccl" if device == "cuda" else "gloo")
    return dist.get_rank(), dist.get_world_size()


def ema_decay(decay: float, updates: int) -> float:
    """The averaging weight of update number ``updates`` (0-based): ``decay``, lowered early
    on ((1 + n) / (10 + n)) so that a run's first hundred steps do not sit in the average for
    thousands more (the warm-up of TensorFlow's ExponentialMovingAverage with num_updates)."""
    return min(decay, (1.0 + updates) / (10.0 + updates))


def ema_update(ema: dict, model, decay: float, updates: int) -> None:
    """One step of the weights' moving average, in place: ``ema[k] ← d·ema[k] + (1 − d)·w[k]``
    for every floating-point entry of ``model.state_dict()`` (BatchNorm's running statistics
    included), integer entries (BatchNorm's step counter) copied; d = :func:`ema_decay`."""
    import torch

    d = ema_decay(decay, updates)
    with torch.no_grad():
        for k, v in model.state_dict().items():
            if v.dtype.is_floating_point:
                ema[k].lerp_(v.detach(), 1.0 - d)
            else:
                ema[k].copy_(v)


# Learning rate at step s of S, as a fraction of the spec's lr.
LR_SCHEDULES = {
    "constant": lambda s, S: 1.0,
    # Cosine to 1/20: the learning curves' test PSNR moved 0.5-1 dB between evaluations at a
    # constant rate; a decayed rate ends on a settled model.
    "cosine": lambda s, S: 0.05 + 0.95 * 0.5 * (1.0 + math.cos(math.pi * min(s, S) / max(S, 1))),
}


def _check_schedule(config: dict) -> None:
    # The specs' default steps (10^6) stand for "until --minutes": nothing to decay over.
    if config.get("lr_schedule", "constant") != "constant" and config["steps"] >= 10 ** 6:
        raise ValueError(f"--lr-schedule {config['lr_schedule']} decays over --steps: give a finite "
                         f"--steps (now {config['steps']})")


def learning_rate(config: dict, step: int) -> float:
    """The optimiser's learning rate for step ``step`` (0-based) of the run ``config``."""
    return config["lr"] * LR_SCHEDULES[config.get("lr_schedule", "constant")](step, config["steps"])


def train(spec_name: str, data: str, out: str, minutes: float | None = None,
          steps: int | None = None, resume: bool = False, batch_size: int | None = None,
          crop: int | None = None, seed: int = 0, threads: int = 0, val_fraction: float = 0.2,
          val_every: int = 0, quiet: bool = False, window: int | None = None,
          spp: list[int] | None = None, temporal_weight: float | None = None,
          max_sequences: int | None = None, test_data: str | None = None, device: str = "cpu",
          lr_schedule: str | None = None, init: str | None = None, fireflies: float = 0.0, lr: float | None = None,
          ema: float | None = None, loader_workers: int = 0, cache_dtype: str = "auto",
          autocast: str | None = None, coarse_weight: float | None = None, cache_dir: str | None = None,
          clip_grad: float | None = None, precise_bn_windows: int | None = None) -> dict:
    """Train and return the final metrics row.  See module docstring.

    ``init``: a run folder whose checkpoint (weights and Adam moments) a new run starts from; the
    data, budget and schedule are this run's own, the step count starts at 0, and the config
    records the source run and its step (``init``), so a chain of sittings on different shards
    stays traceable. Or an exported ``.onnx`` file: its weights only (:func:`_onnx_checkpoint`;
    the config records the file and its sha256, step and chain steps 0).

    ``loader_workers``: processes that build the next batches while the model trains
    (:func:`epoch_batches`); the run is the same with any number, so it is not part of the
    config and a resumed run may use another.

    ``cache_dir``: keep the decoded frames there, memory-mapped (:class:`SequenceDataset`); like
    ``loader_workers`` it changes no item, so it is not part of the config.

    ``clip_grad``: the largest global L2 norm of a step's gradient (None: no clipping). Why:
    a sitting of wskpn-mr-e (docs/results/scale, mr-e sitting 4) lost 2.5 dB between two
    validations at a falling rate, with nothing but the last batch's loss logged to say why.
    Each validation row now carries the interval's training loss mean (``train_loss_mean``)
    and gradient norms before clipping (``grad_norm_median``, ``grad_norm_max``, ``clipped``:
    the steps scaled down); they start again at a resume, so they are a record, not state.

    ``precise_bn_windows``: BatchNorm statistics for validation and export come from
    :func:`precise_bn` over that many training windows (None: :data:`PRECISE_BN_WINDOWS` for a
    new run, a resumed run's own; 0: off). The checkpoint keeps them under ``bn``
    (:func:`runs.load_run` applies them); the live weights and their running averages, which
    training and resume use, are untouched."""
    import torch

    if window is not None and window < 1:
        raise ValueError(f"--window must be >= 1, got {window}")
    if spp is not None and (not spp or min(spp) < 1):
        raise ValueError(f"--spp must be counts >= 1, got {spp}")
    if temporal_weight is not None and not temporal_weight >= 0:
        raise ValueError(f"--temporal-weight must be >= 0, got {temporal_weight}")
    if coarse_weight is not None and not (math.isfinite(coarse_weight) and coarse_weight >= 0):
        raise ValueError(f"--coarse-weight must be >= 0, got {coarse_weight}")
    if ema is not None and not 0.0 < ema < 1.0:
        raise ValueError(f"--ema must be a decay in (0, 1), e.g. 0.995, got {ema}")
    if not 0.0 <= fireflies < 1.0:
        raise ValueError(f"--fireflies must be a mean count per pixel in [0, 1), got {fireflies}")
    if loader_workers < 0:
        raise ValueError(f"--loader-workers must be >= 0, got {loader_workers}")
    if autocast not in (None, "bf16"):
        raise ValueError(f"--autocast must be bf16 or not given, got {autocast!r}")
    if cache_dtype not in ("auto",) + CACHE_DTYPES:
        raise ValueError(f"--cache-dtype must be auto or one of {CACHE_DTYPES}, got {cache_dtype!r}")
    if device not in ("cpu", "cuda"):
        raise ValueError(f"--device must be cpu or cuda, got {device!r}")
    if device == "cuda" and not torch.cuda.is_available():
        raise ValueError("--device cuda: this torch sees no CUDA device")
    rank, world = _distributed(device)
    if device == "cuda" and world > 1:
        torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", rank)))

    from mcdenoise.training.specs import build_model, load_spec

    if threads:
        torch.set_num_threads(threads)
    run = Path(out)
    if init is not None and resume:
        raise ValueError("--init starts a new run; --resume continues one: give one of them")
    if lr is not None and not (math.isfinite(lr) and lr > 0):
        raise ValueError(f"--lr must be a positive number, got {lr}")
    if precise_bn_windows is not None and precise_bn_windows < 0:
        raise ValueError(f"--precise-bn must be a number of windows >= 0, got {precise_bn_windows}")
    if clip_grad is not None and not (math.isfinite(clip_grad) and clip_grad > 0):
        raise ValueError(f"--clip-grad must be a positive norm, got {clip_grad}")
    init_ckpt = None if init is None else _init_checkpoint(init, spec_name)
    if resume:
        if not (run / runs.CONFIG_FILE).exists():
            raise FileNotFoundError(f"{run}: nothing to resume (no {runs.CONFIG_FILE})")
        config = json.loads((run / runs.CONFIG_FILE).read_text())
        spec = load_spec(run / runs.SPEC_FILE)
        if steps is not None:
            config["steps"] = steps
        if minutes is not None:
            config["minutes"] = minutes
        if lr_schedule is not None and lr_schedule != config.get("lr_schedule", "constant"):
            raise ValueError(f"{run}: trained with --lr-schedule {config.get('lr_schedule', 'constant')}; "
                             "a resumed run keeps its schedule")
        if lr is not None and lr != config["lr"]:
            raise ValueError(f"{run}: trained with --lr {config['lr']}; a resumed run keeps its rate")
        if ema is not None and ema != config.get("ema"):
            raise ValueError(f"{run}: trained with --ema {config.get('ema')}; a resumed run keeps its average")
        if autocast is not None and autocast != config.get("autocast"):
            raise ValueError(f"{run}: trained with --autocast {config.get('autocast')}; a resumed run keeps its arithmetic")
        if precise_bn_windows is not None and precise_bn_windows != config.get("precise_bn", 0):
            raise ValueError(f"{run}: trained with --precise-bn {config.get('precise_bn', 0)}; a resumed run keeps its own")
        if clip_grad is not None and clip_grad != config.get("clip_grad"):
            raise ValueError(f"{run}: trained with --clip-grad {config.get('clip_grad')}; a resumed run keeps its clipping")
        if coarse_weight is not None and coarse_weight != config.get("coarse_weight", 0.0):
            raise ValueError(f"{run}: trained with --coarse-weight {config.get('coarse_weight', 0.0)}; "
                             "a resumed run keeps its loss")
        # A run that already reached its steps and scored them returns that score, before reading
        # any frame: resuming a finished arm (scripts that resume every arm) costs nothing.
        rows = runs.read_metrics(run)
        if rows and rows[-1].get("final") and rows[-1].get("step", -1) >= config["steps"]:
            if rank == 0:
                print(f"{run}: already at step {rows[-1]['step']} of {config['steps']}, scored; nothing to do")
            return rows[-1]
    else:
        if (run / runs.CHECKPOINT_FILE).exists():
            raise FileExistsError(f"{run}: already holds a run; use --resume or another --out")
        spec = load_spec(spec_name)
        tr = spec.train
        config = {
            "spec": spec.name, "data": os.path.abspath(data), "seed": seed,
            "steps": steps if steps is not None else tr.steps,
            "minutes": minutes if minutes is not None else tr.minutes,
            "batch_size": batch_size or tr.batch_size, "crop": crop or tr.crop,
            "lr": tr.lr if lr is None else lr, "loss": tr.loss, "spp": list(spp or tr.spp), "window": window or tr.window,
            "temporal_weight": tr.temporal_weight if temporal_weight is None else temporal_weight,
            "coarse_weight": coarse_weight or 0.0,
            "regularizer_weight": tr.regularizer_weight, "lr_schedule": lr_schedule or "constant",
            "ema": ema, "autocast": autocast, "val_fraction": val_fraction, "val_every": val_every,
            "clip_grad": clip_grad,
            "precise_bn": PRECISE_BN_WINDOWS if precise_bn_windows is None else precise_bn_windows,
            "torch": torch.__version__, "argv": sys.argv, "processes": world,
            "max_sequences": max_sequences, "fireflies": fireflies, "test_data": os.path.abspath(test_data) if test_data else None,
            "init": None if init is None else {"run": os.path.abspath(init), "step": init_ckpt["step"],
                                               "chain_steps": init_ckpt["chain_steps"],
                                               **({"sha256": init_ckpt["sha256"]} if "sha256" in init_ckpt else {})},
        }
        spec_path = spec.path if getattr(spec, "path", None) else Path(runs.ROOT / "models_spec" / f"{spec.name}.toml")
        _check_schedule(config)     # before the run folder exists
        config["cache_dtype"] = cache_dtype if cache_dtype != "auto" else _auto_cache_dtype(config, spec, rank, world, cache_dir)
        if rank == 0:
            runs.init_run(run, spec_path, config)
    config.setdefault("temporal_weight", 0.0)     # run folders from before the temporal term
    config.setdefault("coarse_weight", 0.0)       # and from before the coarse term
    config.setdefault("lr_schedule", "constant")
    _check_schedule(config)
    if config["loss"] not in LOSSES:
        raise ValueError(f"unknown loss {config['loss']!r}; known: {sorted(LOSSES)}")
    loss_fn = LOSSES[config["loss"]]
    protocol = spec.protocol

    bs = config["batch_size"]
    if bs % world:
        raise ValueError(f"--batch-size {bs} must be a multiple of the {world} processes")
    torch.manual_seed(config["seed"])
    model = build_model(spec).to(device)
    if device == "cuda" and world > 1:
        model = torch.nn.SyncBatchNorm.convert_sync_batchnorm(model)
    opt = torch.optim.Adam(model.parameters(), lr=config["lr"])
    groups = tuple(g for g, _ in spec.inputs.sample_groups)
    # run folders from before --cache-dtype cached float32
    train_set, val_set, test_set = _datasets(config, spec, config.get("cache_dtype", "float32"), cache_dir)
    val_kw = {"test_set": test_set, "batch_size": bs, "window": config["window"], "device": device}
    steps_per_epoch = max(1, len(train_set) // bs)
    step, epoch, pos, elapsed = 0, 0, 0, 0.0
    if resume and (run / runs.CHECKPOINT_FILE).exists():
        ckpt = torch.load(run / runs.CHECKPOINT_FILE, weights_only=False, map_location=device)
        model.load_state_dict(ckpt["model"])
        opt.load_state_dict(ckpt["optimizer"])
        step, epoch, pos, elapsed = ckpt["step"], ckpt["epoch"], ckpt["pos"], ckpt["elapsed"]
        torch.set_rng_state(ckpt["torch_rng"].cpu())
    elif init_ckpt is not None:
        model.load_state_dict(init_ckpt["model"])      # fits: _init_checkpoint tried it
        if init_ckpt["optimizer"] is not None:          # None from an .onnx file: Adam starts afresh
            opt.load_state_dict(init_ckpt["optimizer"])
    # The average starts from the weights the run starts from: a resumed run's own average, an
    # --init run's source average where it kept one.
    ema_state, ema_updates, ema_model = None, 0, None
    if config.get("ema"):
        src = ckpt if resume and (run / runs.CHECKPOINT_FILE).exists() else init_ckpt
        ema_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        if src is not None and src.get("ema") is not None:
            ema_state = {k: v.to(device) for k, v in src["ema"].items()}
            ema_updates = src.get("ema_updates", 0)
        ema_model = copy.deepcopy(model)
    forward = model
    if world > 1:
        import torch.distributed as dist
        from torch.nn.parallel import DistributedDataParallel

        dist.barrier()      # the run folder exists before anyone may write into it
        forward = DistributedDataParallel(model, device_ids=[torch.cuda.current_device()] if device == "cuda" else None)

    calibrated = {"step": None, "net": None, "bn": None}    # precise_bn of the weights at that step

    def save():
        if rank != 0:
            return
        runs.save_checkpoint(run, {"model": model.state_dict(), "optimizer": opt.state_dict(),
                                   "step": step, "epoch": epoch, "pos": pos, "elapsed": elapsed,
                                   "torch_rng": torch.get_rng_state(), "spec": spec.name,
                                   "ema": ema_state, "ema_updates": ema_updates,
                                   "bn": calibrated["bn"] if calibrated["step"] == step else None})

    def scored():
        """The model validation scores and export ships: the weights' average where the run
        keeps one, with BatchNorm statistics from :func:`precise_bn` where the run asks for them."""
        net = model
        if ema_model is not None:
            ema_model.load_state_dict(ema_state)
            net = ema_model
        if not config.get("precise_bn"):
            return net
        if calibrated["step"] != step:
            cal = precise_bn(net, train_set, protocol, config["precise_bn"], bs, device)
            calibrated.update(step=step, net=cal, bn={k: v.detach().clone() for k, v in cal.state_dict().items()
                                                      if k.endswith(BN_STATS)})
        return calibrated["net"]

    def live():
        """With an average, each validation also scores the live weights ("live_*" metrics), with
        their own calibrated statistics: one run then shows what the average earns at every
        point of its curve."""
        if ema_model is None:
            return None
        return precise_bn(model, train_set, protocol, config.get("precise_bn", 0), bs, device)

    budget_s = None if config["minutes"] is None else 60.0 * config["minutes"]
    bar = None
    if not quiet and rank == 0:
        from tqdm import tqdm

        bar = tqdm(total=config["steps"], initial=step, desc=f"train {spec.name}", unit="step",
                   file=sys.stderr, dynamic_ncols=True)
    # Every frame is read before the first step, by as many processes as the step has threads:
    # read lazily, one decode at a time (0.3-1 s a frame) held up the steps of a sitting's first
    # epochs and left a core idle. The items are the same either way (tested), and the clock of
    # --minutes starts after the reading.
    readers = loader_workers or max(1, threads or torch.get_num_threads())
    if not quiet and rank == 0:
        print(f"train: reading the {sum(len(q.frames) for q in train_set.seqs)} training frames with {readers} "
              f"process(es)" + (f" before {loader_workers} loader processes start" if loader_workers else ""),
              file=sys.stderr)
    for d in (train_set, val_set, test_set):
        if d is not None:
            d.warm(processes=readers)
    model.train()
    interval = _Interval()
    t_start = time.perf_counter() - elapsed
    stopped = budget_s is not None and elapsed >= budget_s     # the same in every process
    while step < config["steps"] and not stopped:
        train_set.set_epoch(epoch)
        order = torch.randperm(len(train_set), generator=torch.Generator().manual_seed(
            config["seed"] * 100003 + epoch)).tolist()
        batches = epoch_batches(EpochBatches(train_set, order, pos, steps_per_epoch, bs, rank, world, bool(groups)),
                                loader_workers, pin=device == "cuda")
        for batch in batches:
            if step >= config["steps"]:
                break
            batch = {k: v.to(device, non_blocking=True) for k, v in batch.items()}
            with torch.autocast(device_type=device, dtype=torch.bfloat16, enabled=config.get("autocast") == "bf16"):
                outs = run_window(model, batch, protocol, forward=forward)
            loss = window_loss(loss_fn, [o[OUTPUT].float() for o in outs], batch["reference"], config["temporal_weight"],
                               config["coarse_weight"])
            if config.get("regularizer_weight") and REGULARIZER in outs[0]:
                loss = loss + config["regularizer_weight"] * sum(o[REGULARIZER].float() for o in outs) / len(outs)
            # The global batch's loss (the mean of the processes' equal shares) and whether the
            # first process's clock says stop: every process takes the same decisions.
            elapsed = time.perf_counter() - t_start
            shared = torch.stack([loss.detach(), torch.tensor(float(budget_s is not None and elapsed >= budget_s),
                                                              device=loss.device)])
            if world > 1:
                dist.all_reduce(shared)
                shared[0] /= world
            if not torch.isfinite(shared[0]):
                raise TrainingDiverged(f"step {step}: loss is {float(shared[0])}; stopping (last checkpoint kept; "
                                       "a lower learning rate or the data's NaN report may help)")
            opt.zero_grad(set_to_none=True)
            loss.backward()
            # After backward DDP's gradients are the global batch's, so every process clips alike.
            norm = float(torch.nn.utils.clip_grad_norm_(model.parameters(), config.get("clip_grad") or math.inf))
            interval.add(float(shared[0]), norm, config.get("clip_grad"))
            for g in opt.param_groups:       # a function of the step alone, so resume stays exact
                g["lr"] = learning_rate(config, step)
            opt.step()
            if ema_state is not None:
                ema_update(ema_state, model, config["ema"], ema_updates)
                ema_updates += 1
            step += 1
            pos += 1
            if bar is not None:
                bar.update(1)
                bar.set_postfix(loss=f"{float(shared[0]):.4f}", epoch=epoch)
            if config["val_every"] and step % config["val_every"] == 0:
                if rank == 0:
                    _validate(run, scored(), val_set, protocol, step, epoch, elapsed, float(shared[0]),
                              interval=interval.take(), live=live(), **val_kw)
                save()
            if shared[1] > 0:
                stopped = True
                break
        batches = None      # a DataLoader's workers end with their iterator
        if pos >= steps_per_epoch:
            pos = 0
            epoch += 1
            if not config["val_every"] and rank == 0:
                _validate(run, scored(), val_set, protocol, step, epoch, elapsed, float(shared[0]),
                          interval=interval.take(), live=live(), **val_kw)
            save()
    if bar is not None:
        bar.close()
    final = scored() if rank == 0 else None     # before the save, which keeps its statistics
    save()
    row = {} if rank != 0 else _validate(run, final, val_set, protocol, step, epoch, elapsed, None, final=True,
                                         interval=interval.take(), live=live(), **val_kw)
    if world > 1:
        # Every process leaves the group together: a process that exits with gloo's threads
        # still running aborts ("terminate called without an active exception", exit -6).
        # DDP's reducer holds the group too, in reference cycles that only the interpreter's
        # teardown would free (the abort seen in CI once): it goes first, while the group lives.
        forward = batches = None
        gc.collect()
        dist.barrier()
        dist.destroy_process_group()
        gc.collect()
    return row


def _init_checkpoint(init: str, spec_name: str) -> dict:
    """The checkpoint of run folder ``init``, checked to be of spec ``spec_name`` or another spec of
    its model type, with
    ``chain_steps``: the steps it and the runs it started from took together."""
    import torch
    from mcdenoise.training.specs import build_model, load_spec

    src = Path(init)
    if src.suffix == ".onnx" and src.is_file():
        return _onnx_checkpoint(src, spec_name)
    if not (src / runs.CHECKPOINT_FILE).exists():
        raise FileNotFoundError(f"--init {src}: no {runs.CHECKPOINT_FILE} there")
    want = load_spec(spec_name)
    cfg = json.loads((src / runs.CONFIG_FILE).read_text())
    # Another spec of the same type may start from it (anf-s -> anf-sd: the same weights on
    # another input path); whether the weights fit is checked below, by loading them.
    have = load_spec(str(src / runs.SPEC_FILE)) if (src / runs.SPEC_FILE).exists() else None
    if cfg["spec"] != want.name and (have is None or have.type != want.type):
        raise ValueError(f"--init {src}: that run trained {cfg['spec']}"
                         f"{f' (type {have.type!r})' if have else ''}, not a spec of type {want.type!r} "
                         f"like {want.name}")
    ckpt = torch.load(src / runs.CHECKPOINT_FILE, weights_only=False, map_location="cpu")
    try:        # before the new run's folder exists
        build_model(want).load_state_dict(ckpt["model"])
    except RuntimeError as e:
        raise ValueError(f"--init {init}: its weights do not fit spec {want.name} ({str(e).splitlines()[0]})") from None
    ckpt["chain_steps"] = ckpt["step"] + ((cfg.get("init") or {}).get("chain_steps") or 0)
    return ckpt


def _onnx_checkpoint(path: Path, spec_name: str) -> dict:
    """A checkpoint-like dict (``model``: the weights; ``optimizer`` None; ``step`` and
    ``chain_steps`` 0; ``sha256`` of the file) read from an exported file of spec ``spec_name``'s
    model type by :func:`mcdenoise.export.onnx_export.load_exported` (every parameter and buffer
    from the initializer of its name: NBG, ANF and NDLE exports keep them; WSKPN's fold each batch
    norm into its convolution, which cannot be undone into the training form, so such a file is
    refused with a clear message rather than half loaded)."""
    import hashlib

    import onnx
    from mcdenoise.export.onnx_export import ExportError, load_exported
    from mcdenoise.runtime.contract import KEY_MODEL_TYPE, KEY_SPEC_NAME
    from mcdenoise.training.specs import load_spec

    want = load_spec(spec_name)
    try:
        meta = {p.key: p.value for p in onnx.load(str(path), load_external_data=False).metadata_props}
    except Exception as e:      # noqa: BLE001  (onnx raises DecodeError and others for a bad file)
        raise ValueError(f"--init {path}: not a readable ONNX file ({type(e).__name__})") from None
    have_type = meta.get(KEY_MODEL_TYPE)
    if have_type is None:
        raise ValueError(f"--init {path}: not an mcdenoise export (no {KEY_MODEL_TYPE} in its metadata)")
    if have_type != want.type:
        raise ValueError(f"--init {path}: that file is a {meta.get(KEY_SPEC_NAME)} ({have_type!r}), "
                         f"not a model of type {want.type!r} like {want.name}")
    try:
        _, model, _ = load_exported(path, spec=want)
    except ExportError as e:
        raise ValueError(f"--init {path}: its weights do not fit spec {want.name} ({e})") from None
    return {"model": model.state_dict(), "optimizer": None, "step": 0, "chain_steps": 0,
            "sha256": hashlib.sha256(path.read_bytes()).hexdigest()}


def _datasets(config: dict, spec, cache_dtype: str, cache_dir: str | None = None):
    """The run's (training, validation, test or None) sets, from its config; their frames kept
    in ``cache_dir`` where given."""
    layers = tuple(spec.inputs.layers)
    groups = tuple(g for g, _ in spec.inputs.sample_groups)
    train_set = SequenceDataset(config["data"], "train", layers, crop=config["crop"],
                                spp_choices=config["spp"], window=config["window"],
                                seed=config["seed"], val_fraction=config["val_fraction"],
                                max_sequences=config.get("max_sequences"), sample_groups=groups,
                                fireflies=config.get("fireflies", 0.0), cache_dtype=cache_dtype, cache_dir=cache_dir)
    val_set = SequenceDataset(config["data"], "val", layers, crop=max(config["crop"], 128),
                              spp_choices=config["spp"], window=config["window"], augment=False,
                              val_fraction=config["val_fraction"], sample_groups=groups, centre_only=True,
                              cache_dtype=cache_dtype, cache_dir=cache_dir)
    test_set = None if not config.get("test_data") else SequenceDataset(
        config["test_data"], "all", layers, crop=max(config["crop"], 128), spp_choices=config["spp"],
        window=config["window"], augment=False, sample_groups=groups, centre_only=True, cache_dtype=cache_dtype,
        cache_dir=cache_dir)
    return train_set, val_set, test_set


def _auto_cache_dtype(config: dict, spec, rank: int, world: int, cache_dir: str | None = None) -> str:
    """``--cache-dtype auto`` for a new run (:func:`training.dataset.cache_dtype_for`): every
    process on this machine caches its own sets, so the need is counted once per local process.
    Rank 0 decides and tells the others, so all train on the same data. With a ``cache_dir``
    the frames that do not fit are read from disk, so float16 is the answer where neither fits
    (slower steps, not a killed run)."""
    from mcdenoise.training.dataset import available_memory, cache_dtype_for

    choice = [None]
    if rank == 0:
        sets = [d for d in _datasets(config, spec, "float32") if d is not None]
        local = int(os.environ.get("LOCAL_WORLD_SIZE", world))
        need = {dt: local * sum(d.cache_bytes(dt) for d in sets) for dt in CACHE_DTYPES}
        available = available_memory()
        try:
            choice[0] = cache_dtype_for(need["float32"], need["float16"], available)
        except MemoryError:
            if not cache_dir:
                raise
            choice[0] = "float16"
            print(f"train: the frames need {need['float16'] / 2**30:.1f} GB in float16, more than the memory holds: "
                  f"the rest is read from {cache_dir} as the steps need it", file=sys.stderr)
        if choice[0] != "float32":
            print(f"train: the frames would take {need['float32'] / 2**30:.1f} GB in float32, more than {CACHE_MEMORY_FRACTION:.0%} of the "
                  f"{available / 2**30:.1f} GB available: caching their samples in float16 "
                  f"({need[choice[0]] / 2**30:.1f} GB; --cache-dtype)", file=sys.stderr)
    if world > 1:
        import torch.distributed as dist

        dist.broadcast_object_list(choice, src=0)
    return choice[0]


class _Interval:
    """The training steps since the last validation row: loss and gradient-norm statistics."""

    def __init__(self):
        self.losses, self.norms, self.clipped = [], [], 0

    def add(self, loss: float, norm: float, clip: float | None) -> None:
        self.losses.append(loss)
        self.norms.append(norm)
        self.clipped += bool(clip is not None and norm > clip)

    def take(self) -> dict:
        """The interval's statistics for a metrics row (empty after no step), and a new interval."""
        row = {} if not self.norms else {
            "interval_steps": len(self.norms), "train_loss_mean": float(np.mean(self.losses)),
            "grad_norm_median": float(np.median(self.norms)), "grad_norm_max": float(np.max(self.norms)),
            "clipped": self.clipped}
        self.__init__()
        return row


def _validate(run, model, val_set, protocol, step, epoch, elapsed, loss, final=False, test_set=None,
              batch_size: int = 1, window: int = 1, device: str = "cpu", live=None, interval: dict | None = None) -> dict:
    row = {"step": step, "epoch": epoch, "elapsed_s": round(elapsed, 1), "train_loss": loss,
           "final": final, "examples": step * batch_size, "frames_seen": step * batch_size * window,
           **(interval or {}), **evaluate(model, val_set, protocol, device=device)}
    if test_set is not None:
        row.update({"test" + k[3:]: v for k, v in evaluate(model, test_set, protocol, device=device).items() if k.startswith("val_")})
    if live is not None:
        row.update({"live_" + k: v for k, v in evaluate(live, val_set, protocol, device=device).items() if k.startswith("val_")})
        if test_set is not None:
            row.update({"live_test" + k[3:]: v for k, v in evaluate(live, test_set, protocol, device=device).items()
                        if k.startswith("val_")})
    runs.append_metrics(run, row)
    print(f"[step {step} epoch {epoch}] val PSNR {row['val_psnr']:.2f} dB (noisy {row['noisy_psnr']:.2f}), "
          f"SMAPE {row['val_smape']:.4f}", file=sys.stderr)
    return row


def main(args) -> int:
    if args.minutes is not None and args.minutes <= 0:
        raise ValueError("--minutes must be positive")
    row = train(args.spec, args.data, args.out, minutes=args.minutes, steps=args.steps,
                resume=args.resume, batch_size=args.batch_size, crop=args.crop, seed=args.seed,
                threads=args.threads, val_fraction=args.val_fraction, val_every=args.val_every,
                quiet=args.quiet, window=args.window, spp=args.spp, temporal_weight=args.temporal_weight,
                max_sequences=args.max_sequences, test_data=args.test, device=args.device,
                lr_schedule=args.lr_schedule, lr=args.lr, init=args.init, fireflies=args.fireflies, ema=args.ema,
                loader_workers=args.loader_workers, cache_dtype=args.cache_dtype, cache_dir=args.cache_dir, autocast=args.autocast,
                coarse_weight=args.coarse_weight, clip_grad=args.clip_grad, precise_bn_windows=args.precise_bn)
    print(json.dumps(row, indent=2))
    return 0
