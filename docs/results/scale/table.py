"""The scale sittings' scores beside the shipped models' and Open Image Denoise's, as markdown.

    python docs/results/scale/table.py > docs/results/scale/table.md

Reads every ``*.json`` of ``mcdenoise evaluate`` under docs/results/scale (the runs' own,
written by sitting.sh, and baseline/, written by baseline.sh), all on data/curves-test."""
import json
from pathlib import Path

HERE = Path(__file__).resolve().parent


def load() -> dict:
    """{(kind, spp): {method: result}} for kind "sequences" (after warm-up) and "stills"."""
    out: dict = {}
    for p in sorted(HERE.rglob("*.json")):
        d = json.loads(p.read_text())
        setup = d.get("_setup")
        if not setup:
            continue
        kind = "stills" if setup["stills"] else "sequences"
        for m, r in d.items():
            if m == "_setup":
                continue
            # a spec's name says which model, not which weights: the shipped file or a sitting's run
            if m != "noisy" and not m.startswith("oidn"):
                m = f"{m} (shipped)" if p.parent.name == "baseline" else f"{m} ({p.parent.name})"
            if kind == "sequences":
                r = dict(r["after_warmup"], trmae=r["after_warmup"].get("trmae"))
            out.setdefault((kind, setup["spp"]), {})[m] = r
    return out


def main() -> None:
    res = load()
    methods = sorted({m for v in res.values() for m in v}, key=lambda m: (m != "noisy", m.startswith("oidn"), m))
    print("# data/curves-test (4 held-out procedural scenes x 8 frames, 128x128, seed 11)\n")
    print("Sequences through the driver with history, scored after 2 warm-up frames; PSNR dB "
          "(ANF Eq. 14), relMSE, TRMAE (Eq. 16).\n")
    spps = sorted(s for k, s in res if k == "sequences")
    print("| method | " + " | ".join(f"{s} spp PSNR | relMSE | TRMAE" for s in spps) + " |")
    print("|---|" + "---:|---:|---:|" * len(spps))
    for m in methods:
        cells = []
        for s in spps:
            r = res[("sequences", s)].get(m)
            cells += ["-"] * 3 if r is None else [f"{r['psnr']:.2f}", f"{r['relmse']:.3f}",
                                                   "-" if r.get("trmae") is None else f"{r['trmae']:.3f}"]
        print(f"| {m} | " + " | ".join(cells) + " |")
    spps = sorted(s for k, s in res if k == "stills")
    print("\nStills (each sequence's first frame, no history), PSNR dB:\n")
    print("| method | " + " | ".join(f"{s} spp" for s in spps) + " | monotonic |")
    print("|---|" + "---:|" * len(spps) + "---|")
    for m in methods:
        v = [res[("stills", s)].get(m, {}).get("psnr") for s in spps]
        mono = all(a is not None and b is not None and b > a for a, b in zip(v, v[1:]))
        print(f"| {m} | " + " | ".join("-" if x is None else f"{x:.2f}" for x in v) + f" | {'yes' if mono else 'no'} |")


if __name__ == "__main__":
    main()
