"""The run folder: the record of one training run, and the only source export rebuilds from.

Layout of ``RUN/``::

    spec.toml        the model spec as trained (a copy, so later edits to models_spec/ don't leak in)
    config.json      final training configuration (data, seeds, steps, optimiser, ...)
    checkpoint.pt    {"model": state_dict, "optimizer": ..., "step": int, "rng": ..., "ema": state_dict
                     or None, ...}: "model" is what the optimiser steps and resume continues;
                     "ema", where the run averages its weights (train --ema), is what it ships
    metrics.jsonl    one JSON object per validation (step, epoch, val metrics, wall time)
    code_hash.txt    sha256 over the package's source files and the spec
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

from mcdenoise.runtime import DATA_ROOT as ROOT

SPEC_FILE = "spec.toml"
CONFIG_FILE = "config.json"
CHECKPOINT_FILE = "checkpoint.pt"
METRICS_FILE = "metrics.jsonl"
CODE_HASH_FILE = "code_hash.txt"


def code_hash() -> str:
    """sha256 of every tracked-kind source file of the package (runtime, training, export, specs)."""
    h = hashlib.sha256()
    for sub in ("runtime", "training", "export", "models_spec"):
        for p in sorted((ROOT / sub).rglob("*")):
            if p.suffix in (".py", ".toml") and "__pycache__" not in p.parts:
                h.update(str(p.relative_to(ROOT)).encode())
                h.update(p.read_bytes())
    return h.hexdigest()


def init_run(run_dir: str | os.PathLike, spec_path: str | os.PathLike, config: dict) -> Path:
    """Create ``run_dir`` with the spec copy, config and code hash."""
    run = Path(run_dir)
    run.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(spec_path, run / SPEC_FILE)
    (run / CONFIG_FILE).write_text(json.dumps(config, indent=2, sort_keys=True) + "\n")
    (run / CODE_HASH_FILE).write_text(code_hash() + "\n")
    return run


def load_run(run_dir: str | os.PathLike, map_location: str = "cpu"):
    """Rebuild ``(spec, model, checkpoint)`` from a run folder alone (eval mode, weights loaded:
    the run's weight average where it kept one, else its last weights; BatchNorm statistics
    from the checkpoint's ``bn`` where the run estimated them afresh).

    Raises FileNotFoundError naming the missing file, ValueError for a checkpoint that cannot
    be read or does not fit the spec.
    """
    import torch

    from mcdenoise.training.specs import build_model, load_spec

    run = Path(run_dir)
    for name in (SPEC_FILE, CHECKPOINT_FILE):
        if not (run / name).exists():
            raise FileNotFoundError(f"{run}: not a run folder (missing {name})")
    spec = load_spec(run / SPEC_FILE)
    model = build_model(spec)
    try:
        ckpt = torch.load(run / CHECKPOINT_FILE, map_location=map_location, weights_only=False)
    except Exception as e:  # truncated, not a torch file, written by an incompatible torch
        raise ValueError(f"{run / CHECKPOINT_FILE}: not a readable checkpoint ({type(e).__name__}: "
                         f"{' '.join(str(e).split())[:300]})") from None
    if not isinstance(ckpt, dict) or "model" not in ckpt:
        raise ValueError(f"{run / CHECKPOINT_FILE}: holds no model weights")
    try:
        model.load_state_dict(ckpt["ema"] if ckpt.get("ema") is not None else ckpt["model"])
    except RuntimeError as e:  # the spec was edited after training, or files from two runs
        first = next((ln.strip() for ln in str(e).splitlines()[1:] if ln.strip()), str(e))
        raise ValueError(f"{run}: the checkpoint does not match {SPEC_FILE} ({first})") from None
    if ckpt.get("bn"):     # BatchNorm statistics estimated afresh (training.train.precise_bn)
        model.load_state_dict({**model.state_dict(), **ckpt["bn"]})
    model.eval()
    return spec, model, ckpt


def save_checkpoint(run_dir: str | os.PathLike, state: dict) -> None:
    """Atomically write ``checkpoint.pt`` (a crash mid-save keeps the previous one)."""
    import torch

    run = Path(run_dir)
    tmp = run / (CHECKPOINT_FILE + ".tmp")
    torch.save(state, tmp)
    os.replace(tmp, run / CHECKPOINT_FILE)


def append_metrics(run_dir: str | os.PathLike, row: dict) -> None:
    with open(Path(run_dir) / METRICS_FILE, "a") as fh:
        fh.write(json.dumps(row, sort_keys=True) + "\n")


def read_metrics(run_dir: str | os.PathLike) -> list[dict]:
    p = Path(run_dir) / METRICS_FILE
    if not p.exists():
        return []
    return [json.loads(line) for line in p.read_text().splitlines() if line.strip()]
