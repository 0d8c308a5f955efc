"""The quality tables of a scale run's model card, from committed evaluations only.

    python docs/results/scale/card_tables.py wskpn-6e-6 > docs/results/scale/card-wskpn-6e-6.md
    python docs/results/scale/card_tables.py wskpn-mr-e-3 wskpn-6e-6   # beside another run's columns

Reads docs/results/long/<set>/<RUN>-<spp>spp.json and baseline-<spp>spp.json (eval.sh), and the
run folder's and docs/results/scale/baseline's curves-test files (sitting.sh, baseline.sh).
PSNR dB on tonemapped radiance after warm-up (8 frames on the long sets, 2 on curves-test), with
history; TRMAE beside it. Compared: the shipped wskpn-6 and wskpn-3, our SVGF-style filter and Open
Image Denoise fast / high, all through the same runtime API."""
import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
LONG = HERE.parent / "long"
SETS = ("heldout-room_window", "heldout-lamp_occluder", "long-slow", "long-medium", "long-fast")
BASELINE = ("wskpn-6", "wskpn-3", "svgf", "oidn-fast", "oidn-high")


def scores(path: Path, warm: bool = True) -> dict:
    d = json.loads(path.read_text())
    d.pop("_setup")
    return {m: (r.get("after_warmup") or r) if warm else r for m, r in d.items()}


def cell(r: dict | None) -> str:
    if not r:
        return "-"
    t = r.get("trmae")
    return f"{r['psnr']:.2f}" + (f" / {t:.3f}" if t is not None else "")


def main(run: str, *others: str) -> None:
    """``others``: run folders (e.g. the shipped model's) whose columns follow ``run``'s."""
    runs = (run, *others)
    spec = {r: json.loads((HERE / r / "config.json").read_text())["spec"] for r in runs}
    print(f"Made by `python docs/results/scale/card_tables.py {' '.join(runs)}`.\n")
    print("Long sequences and hand-made scenes, after 8 warm-up frames, with history: PSNR dB / TRMAE\n")
    cols = [f"{spec[r]} ({r})" for r in runs] + list(BASELINE)
    print("| set | spp | " + " | ".join(cols) + " |")
    print("|---|---:|" + "---:|" * len(cols))
    for s in SETS:
        for spp in (1, 4):
            own, base = LONG / s / f"{run}-{spp}spp.json", LONG / s / f"baseline-{spp}spp.json"
            if not own.exists() or not base.exists():
                continue
            b = scores(base)
            mine = [cell(scores(f).get(spec[r])) if (f := LONG / s / f"{r}-{spp}spp.json").exists() else "-"
                    for r in runs]
            print(f"| {s} | {spp} | " + " | ".join(mine + [cell(b.get(m)) for m in BASELINE]) + " |")
    print("\ncurves-test (4 procedural scenes x 8 frames, 128x128, seed 11): sequences after 2 warm-up "
          "frames, PSNR dB / TRMAE; stills (first frames) PSNR dB\n")
    print("| method | sequences 1 spp | 4 spp | stills 1 | 2 | 4 | 8 spp |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    rows = {f"{spec[r]} ({r})": (HERE / r, spec[r]) for r in runs}
    rows.update({m: (HERE / "baseline", m) for m in ("wskpn-6", "oidn-high")})
    for label, (folder, key) in rows.items():
        seq = [cell(scores(folder / f"curves-test-{spp}spp.json").get(key)) for spp in (1, 4)]
        still = []
        for spp in (1, 2, 4, 8):
            p = folder / f"stills-curves-test-{spp}spp.json"
            r = scores(p, warm=False).get(key) if p.exists() else None
            still.append(f"{r['psnr']:.2f}" if r else "-")
        print(f"| {label} | " + " | ".join(seq + still) + " |")


if __name__ == "__main__":
    main(*sys.argv[1:])
