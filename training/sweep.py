"""``mcdenoise sweep MODEL --data DIR --setting kernel_size --values 3 5 ... 19``: quality and
time against a run-time setting (ANF Fig. 7: kernel size against PSNR, TRMAE and time).

The model file is loaded once; for each value the setting is changed on the running driver
(:meth:`runtime.denoiser.Denoiser.set`: no re-export, no re-load) and every sequence of
``--data`` goes through it frame by frame at ``--spp`` (history on, reset between sequences),
scored as ``mcdenoise evaluate`` scores (:func:`training.scoring.run_methods`, after
``--warmup`` frames too). Time: the driver's median whole-frame time over those same frames
(the first frame of each value left out as warm-up), measured in the same run for every value.
Writes ``sweep.json``, ``sweep.md`` (the command and the table) and ``sweep.png``.
"""
from __future__ import annotations

import json
import statistics
from pathlib import Path

from mcdenoise.runtime.args import CommandError, add_data, add_threads
from mcdenoise.runtime import timing


def sweep(model: str, data: str, setting: str, values: list[int], spp: int = 4, warmup: int = 0,
          threads: int = 0, log=print) -> dict:
    """{value: {"psnr", "trmae", "wte", "ms", [after_warmup]}} (see the module docstring)."""
    from mcdenoise.training.methods import ONNXModel
    from mcdenoise.training.scoring import run_methods
    from mcdenoise.training.testsets import read_sequences

    method = ONNXModel(model, threads=threads)
    den = method.denoiser
    if setting not in den.settings:
        raise CommandError(f"{model}: no run-time setting {setting!r}; it has {sorted(den.settings) or 'none'}")
    seqs = read_sequences(data)
    out = {}
    for v in values:
        try:
            den.set(setting, v)
        except ValueError as e:
            raise CommandError(f"--values: {e}") from None
        first = len(den.timings)
        res = run_methods([method], seqs, spp, log=lambda m: None, warmup=warmup)[method.name]
        ms = [t[timing.TOTAL] for t in den.timings[first + 1:]] or [den.timings[-1][timing.TOTAL]]
        out[v] = {**{k: res[k] for k in ("psnr", "trmae", "wte", "frames")}, "ms": statistics.median(ms),
                  "after_warmup": res.get("after_warmup")}
        log(f"{setting} = {v}: PSNR {res['psnr']:.2f} dB, TRMAE {res['trmae']:.4f}, {out[v]['ms']:.0f} ms/frame")
    return out


def write(results: dict, out: str, setting: str, command: str, model: str, spp: int) -> None:
    """sweep.json, sweep.md and sweep.png in ``out``."""
    d = Path(out)
    d.mkdir(parents=True, exist_ok=True)
    (d / "sweep.json").write_text(json.dumps({"command": command, "setting": setting, "spp": spp,
                                              "results": {str(k): v for k, v in results.items()}}, indent=2) + "\n")
    aw = any(r.get("after_warmup") for r in results.values())
    lines = [f"# {Path(model).name}: quality and time against {setting} ({spp} spp)", "", f"`{command}`", "",
             f"| {setting} | PSNR dB | TRMAE | WTE |" + (" PSNR after warm-up |" if aw else "") + " ms / frame |",
             "|---:|---:|---:|---:|" + ("---:|" if aw else "") + "---:|"]
    for v, r in results.items():
        a = r.get("after_warmup") or {}
        lines.append(f"| {v} | {r['psnr']:.2f} | {r['trmae']:.4f} | {r['wte']:.3f} |"
                     + (f" {a['psnr']:.2f} |" if aw and a else (" - |" if aw else "")) + f" {r['ms']:.0f} |")
    (d / "sweep.md").write_text("\n".join(lines) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xs = list(results)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.5))
    ax1.plot(xs, [results[x]["psnr"] for x in xs], "o-", label="PSNR")
    ax1.set_xlabel(setting)
    ax1.set_ylabel("PSNR dB")
    twin = ax1.twinx()
    twin.plot(xs, [results[x]["trmae"] for x in xs], "s--", color="C1", label="TRMAE")
    twin.set_ylabel("TRMAE")
    ax2.plot(xs, [results[x]["ms"] for x in xs], "o-", color="C2")
    ax2.set_xlabel(setting)
    ax2.set_ylabel("ms / frame (driver)")
    fig.suptitle(f"{Path(model).name} at {spp} spp")
    fig.tight_layout()
    fig.savefig(d / "sweep.png", dpi=110)
    plt.close(fig)


def add_arguments(p):
    p.add_argument("model", help="an mcdenoise ONNX file with run-time settings (e.g. ANF's kernel_size)")
    add_data(p)
    p.add_argument("--setting", default="kernel_size", help="the setting to sweep (default kernel_size)")
    p.add_argument("--values", type=int, nargs="+", required=True, help="its values, e.g. 3 5 7 9 11 13 15 17 19")
    p.add_argument("--spp", type=int, default=4, help="samples per pixel fed to the model (default 4, as Fig. 7)")
    p.add_argument("--warmup", type=int, default=0, help="also score the frames after the first N of each sequence")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for sweep.json, sweep.md, sweep.png")
    add_threads(p)


def main(args) -> int:
    from mcdenoise.runtime.cli import command_line

    res = sweep(args.model, args.data, args.setting, args.values, args.spp, args.warmup, args.threads)
    write(res, args.out, args.setting, command_line("sweep", args), args.model, args.spp)
    print(f"wrote {Path(args.out) / 'sweep.md'}")
    return 0
