"""The high-spp runs' scores beside the shipped models' and Open Image Denoise's, as markdown.

    python docs/results/highspp/table.py > docs/results/highspp/table.md

Reads only committed evaluations (``mcdenoise evaluate --json``), made by score.sh:
  - stills on data/curves-test: each run folder's, baseline/ here and docs/results/scale/baseline;
  - the held-out sets at 1 and 4 spp: docs/results/long/<set>/{baseline,wskpn-6e-6,<run>}-<spp>spp.json
    (wskpn-6e-6 is the run the shipped wskpn-6e was exported from);
  - the held-out sets at 8 spp: <set>-8spp.json here.
PSNR dB on tonemapped radiance (ANF Eq. 14); sequences after 8 warm-up frames, with TRMAE (Eq. 16)."""
import json
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE.parent
RUNS = ("wskpn-mr", "nbg-7l-3g")
SETS = ("heldout-room_window", "heldout-lamp_occluder", "long-slow", "long-medium", "long-fast")
SHOWN = ("wskpn-6e", "wskpn-3", "nbg-2l-3g", "anf-s", "svgf", "oidn-fast", "oidn-high")


def load(path: Path) -> dict:
    """{method: result} of one evaluation file (results after warm-up where it has them)."""
    d = json.loads(path.read_text())
    d.pop("_setup", None)
    return {m: r.get("after_warmup") or r for m, r in d.items() if "(no history)" not in m}


def stills() -> dict:
    """{spp: {method: psnr}} on curves-test's stills."""
    out: dict = {}
    for spp in (1, 2, 4, 8):
        row = out.setdefault(spp, {})
        for p in (RESULTS / "scale/baseline", HERE / "baseline", *(HERE / r for r in RUNS)):
            f = p / f"stills-curves-test-{spp}spp.json"
            if f.exists():
                row.update({m: r["psnr"] for m, r in load(f).items()})
    return out


def sequences(name: str, spp: int) -> dict:
    """{method: result} on one held-out set at one spp, or {} where it was not scored."""
    files = [HERE / f"{name}-{spp}spp.json"] if spp == 8 else \
        [RESULTS / "long" / name / f"{w}-{spp}spp.json" for w in ("baseline", "wskpn-6e-6", *RUNS)]
    row: dict = {}
    for f in files:
        if f.exists():
            row.update(load(f))
    return row


def cell(r) -> str:
    if r is None:
        return "-"
    if isinstance(r, float):
        return f"{r:.2f}"
    t = r.get("trmae")
    return f"{r['psnr']:.2f}" + (f" / {t:.3f}" if t is not None else "")


def main() -> None:
    cols = [*RUNS, *SHOWN]
    print("# High-spp models (issue 15): wskpn-mr and nbg-7l-3g beside the shipped models\n")
    print("Made by `python docs/results/highspp/table.py` from score.sh's evaluations.\n")
    print("## data/curves-test stills (first frames, no history), PSNR dB\n")
    st = stills()
    print("| spp | " + " | ".join(cols) + " |")
    print("|---:|" + "---:|" * len(cols))
    for spp, row in st.items():
        print(f"| {spp} | " + " | ".join(cell(row.get(c)) for c in cols) + " |")
    print("\n## Held-out sequences after 8 warm-up frames, with history: PSNR dB / TRMAE\n")
    print("| set | spp | " + " | ".join(cols) + " |")
    print("|---|---:|" + "---:|" * len(cols))
    for name in SETS:
        for spp in (1, 4, 8):
            row = sequences(name, spp)
            if row:
                print(f"| {name} | {spp} | " + " | ".join(cell(row.get(c)) for c in cols) + " |")


if __name__ == "__main__":
    main()
