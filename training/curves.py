"""``mcdenoise curves SPEC --data DIR --test DIR``: learning curves, to find what limits a model.

Trains ``SPEC`` on nested subsets of the training split (``--sequences``: the first N
sequences by scene seed) and, optionally, on variants of one ``[params]`` value
(``--vary KEY VALUE...``, e.g. ``--vary widths "[8]" "[16]"``), every run scoring the held-out
``--test`` folder at each validation (``mcdenoise train --test``). The curves are test PSNR
(ANF Eq. 14, last frame of each window, the history warmed up) against training examples
seen (windows of ``window`` frames): a curve still rising wants more steps; curves that part
by data size want more data; widths that part want a wider (or narrower) network.

Each run is a run folder under ``--out`` (``<spec>[-<key>-<value>]-n<N>``); running the
command again resumes every run (``--steps`` may grow), so curves extend across sittings.
Writes ``curves.json``, ``curves.md`` (the command, the final points) and ``curves.png``.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

from mcdenoise.runtime.args import add_data, add_seed, add_threads

#: Metric plotted, from each run's metrics.jsonl.
Y = "test_psnr"


def spec_variant(text: str, key: str, value: str) -> str:
    """The spec TOML ``text`` with ``key = value`` set in its ``[params]`` table (the value as
    TOML; a key the table lacks is added at its top, and building the model then refuses a key
    its type does not have) and its name suffixed with the change."""
    lines = text.splitlines()
    table, done, params_at = None, False, None
    for i, line in enumerate(lines):
        head = re.match(r"^\s*\[+([^\]]+)\]+\s*(#.*)?$", line)
        if head:
            table = head.group(1).strip()
            if table == "params" and line.strip().startswith("[params]"):
                params_at = i
            continue
        if table == "params" and re.match(rf"^\s*{re.escape(key)}\s*=", line):
            lines[i] = f"{key} = {value}"
            done = True
        elif table is None and re.match(r"^\s*name\s*=", line):
            name = re.search(r'=\s*"([^"]+)"', line).group(1)
            tag = re.sub(r"[^a-z0-9.]+", "-", f"{key}-{value}".lower()).strip("-")
            lines[i] = f'name = "{name}-{tag}"'
    if not done:
        if params_at is None:
            raise ValueError(f"--vary {key}: the spec has no [params] table")
        lines.insert(params_at + 1, f"{key} = {value}")
    return "\n".join(lines) + "\n"


def curves(spec: str, data: str, test: str, out: str, sequences=(None,), vary: tuple | None = None,
           steps: int = 2000, eval_every: int = 250, log=print, **train_kw) -> dict:
    """Train every (variant, sequence count) run and collect its test curve; see the module
    docstring. ``train_kw`` goes to :func:`training.train.train` (batch size, crop, window,
    spp, seed, threads, ...). Returns {run name: {"variant", "sequences", "points": [(examples,
    frames, test PSNR), ...]}}."""
    from mcdenoise.training import runs
    from mcdenoise.training.specs import build_model, load_spec, parse_spec
    from mcdenoise.training.train import train

    base = load_spec(spec)
    outp = Path(out)
    (outp / "specs").mkdir(parents=True, exist_ok=True)
    variants = [(None, base.path)]
    if vary:
        key, values = vary[0], vary[1:]
        variants = []
        for v in values:
            text = spec_variant(base.path.read_text(), key, v)
            # Named by the variant (its spec name), not by its position: two processes training
            # different values into one --out must not overwrite each other's spec file.
            path = outp / "specs" / f"{parse_spec(text).name}.toml"
            path.write_text(text)
            build_model(load_spec(path))          # a bad key or value fails here, before any training
            variants.append((f"{key}={v}", path))
    result = {}
    for label, spec_path in variants:
        for n in sequences:
            name = load_spec(spec_path).name + (f"-n{n}" if n else "-all")
            run = outp / name
            resume = (run / runs.CHECKPOINT_FILE).exists()
            log(f"curves: {name}: {'resuming' if resume else 'training'} to step {steps}")
            train(str(spec_path), data, str(run), steps=steps, resume=resume, val_every=eval_every,
                  max_sequences=n, test_data=test, quiet=True, **train_kw)
            rows = [r for r in runs.read_metrics(run) if r.get(Y) is not None]
            result[name] = {"variant": label, "sequences": n, "points": sorted(
                {(r["examples"], r["frames_seen"], r[Y]) for r in rows})}
    return result


def write(result: dict, out: str, command: str) -> None:
    outp = Path(out)
    (outp / "curves.json").write_text(json.dumps({"command": command, "runs": result}, indent=1) + "\n")
    lines = ["# Learning curves", "", f"Written by `{command}`. Test PSNR (ANF Eq. 14) against training "
             "examples seen; the last point of each run:", "",
             "| run | variant | training sequences | examples | frames | test PSNR dB |", "|---|---|---:|---:|---:|---:|"]
    for name, r in result.items():
        if r["points"]:
            ex, fr, y = r["points"][-1]
            lines.append(f"| {name} | {r['variant'] or '-'} | {r['sequences'] or 'all'} | {ex} | {fr} | {y:.2f} |")
    (outp / "curves.md").write_text("\n".join(lines + ["", "![curves](curves.png)", ""]))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name, r in result.items():
        if r["points"]:
            xs, _, ys = zip(*r["points"])
            ax.plot(xs, ys, marker="o", ms=3, label=name)
    ax.set_xscale("log")
    ax.set_xlabel("training examples seen (windows)")
    ax.set_ylabel("test PSNR dB")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(outp / "curves.png", dpi=120, metadata={"Description": command})
    plt.close(fig)


def add_arguments(p) -> None:
    p.add_argument("spec", help="model spec name (models_spec/<name>.toml) or path")
    add_data(p)
    p.add_argument("--test", required=True, metavar="DIR", help="held-out folder of sequences scored at each validation")
    p.add_argument("--out", required=True, metavar="DIR", help="folder of the run folders and the curves")
    p.add_argument("--sequences", type=int, nargs="+", default=None,
                   help="training-set sizes: the first N training sequences (default: all of them)")
    p.add_argument("--vary", nargs="+", metavar=("KEY", "VALUE"), default=None,
                   help="a [params] key and the TOML values to train, e.g. --vary widths '[8]' '[16]'")
    p.add_argument("--steps", type=int, default=2000, help="optimiser steps of every run (default 2000)")
    p.add_argument("--eval-every", type=int, default=250, help="steps between test scores (default 250)")
    p.add_argument("--batch-size", type=int, default=None)
    p.add_argument("--crop", type=int, default=None)
    p.add_argument("--window", type=int, default=None)
    p.add_argument("--spp", type=int, nargs="+", default=None)
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu", help="where every run trains")
    p.add_argument("--ema", type=float, default=None, metavar="DECAY",
                   help="every run keeps a moving average of its weights, which the curve scores (train --ema)")
    add_seed(p, "initial weights and the order of examples of every run")
    add_threads(p)


def main(args) -> int:
    from mcdenoise.runtime.cli import command_line

    if args.vary is not None and len(args.vary) < 2:
        raise ValueError("--vary needs a key and at least one value")
    if args.eval_every < 1 or args.steps < 1:
        raise ValueError("--steps and --eval-every must be >= 1")
    res = curves(args.spec, args.data, args.test, args.out, sequences=tuple(args.sequences or (None,)),
                 vary=tuple(args.vary) if args.vary else None, steps=args.steps, eval_every=args.eval_every,
                 batch_size=args.batch_size, crop=args.crop, window=args.window, spp=args.spp, seed=args.seed,
                 threads=args.threads, device=args.device, minutes=1e9, ema=args.ema)
    write(res, args.out, command_line("curves", args))
    print(f"wrote {args.out}/curves.md, curves.json and curves.png")
    return 0
