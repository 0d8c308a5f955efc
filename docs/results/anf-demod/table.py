"""The anf-demod A/B (train.sh, score.sh) beside the shipped anf-s, wskpn-6e and Open Image
Denoise high, as markdown:

    python docs/results/anf-demod/table.py > docs/results/anf-demod/table.md

Reads only committed evaluations (``mcdenoise evaluate --json``):
  - the runs': <run>/curves-test-<spp>spp.json, <run>/stills-curves-test-<spp>spp.json and
    <set>/<run>-<spp>spp.json here;
  - the shipped models': docs/results/anf/curves-test-<spp>spp.json (anf-s on curves-test),
    docs/results/stills-spp/<set>-<spp>.json (stills),
    docs/results/long/<set>/{baseline,wskpn-6e-6}-<spp>spp.json (1 and 4 spp; wskpn-6e-6 is the
    run wskpn-6e was exported from) and docs/results/highspp/<set>-8spp.json (8 spp).
PSNR dB on tonemapped radiance (ANF Eq. 14) / TRMAE (Eq. 16), with history; sequences after
their warm-up (2 frames on curves-test, 8 on the held-out sets)."""
from pathlib import Path

from mcdenoise.training.evaluate import load_results as load   # {method: after warm-up}, {} if missing

HERE = Path(__file__).resolve().parent
RESULTS = HERE.parent
RUNS = ("anf-s-ft", "anf-sd")
SETS = ("long-slow", "heldout-room_window", "heldout-lamp_occluder")
#: (column, method key in the shipped files)
SHIPPED = (("anf-s (shipped)", "anf-s"), ("wskpn-6e", "wskpn-6e"), ("oidn-high", "oidn-high"))


def run_result(path: Path):
    """The one model's result in a run's evaluation file (keyed by its spec's name, beside
    "noisy"), or None."""
    d = {m: r for m, r in load(path).items() if m != "noisy"}
    return next(iter(d.values())) if d else None


def shipped(files: list[Path]) -> dict:
    row: dict = {}
    for f in files:
        row.update(load(f))
    return row


def cell(r) -> str:
    if r is None:
        return "-"
    t = r.get("trmae")
    return f"{r['psnr']:.2f}" + (f" / {t:.3f}" if t is not None else "")


def main() -> None:
    cols = [c for c, _ in SHIPPED[:1]] + list(RUNS) + [c for c, _ in SHIPPED[1:]]
    print("# ANF on albedo-demodulated irradiance (issue 16): the A/B of train.sh\n")
    print("Made by `python docs/results/anf-demod/table.py` from score.sh's evaluations and the committed")
    print("shipped-model evaluations. PSNR dB / TRMAE, with history, after warm-up.\n")
    for name in ("curves-test", "long-slow"):
        print(f"## data/{name} stills (first frames, no history), PSNR dB\n")
        print("| spp | " + " | ".join(["anf-s (shipped)", "anf-s-ft", "anf-sd", "wskpn-6", "oidn-high"]) + " |")
        print("|---:|---:|---:|---:|---:|---:|")
        for spp in (1, 2, 4, 8):
            base = shipped([RESULTS / "stills-spp" / f"{name}-{spp}.json"])
            cells = [base.get("anf-s")] + [run_result(HERE / r / f"stills-{name}-{spp}spp.json") for r in RUNS]
            cells += [base.get("wskpn-6"), base.get("oidn-high")]
            print(f"| {spp} | " + " | ".join("-" if c is None else f"{c['psnr']:.2f}" for c in cells) + " |")
        print()
    print("## Sequences\n")
    print("| set | spp | " + " | ".join(cols) + " |")
    print("|---|---:|" + "---:|" * len(cols))
    for spp in (1, 4):
        base = shipped([RESULTS / "anf" / f"curves-test-{spp}spp.json"])
        runs = [run_result(HERE / r / f"curves-test-{spp}spp.json") for r in RUNS]
        print(f"| curves-test | {spp} | " + " | ".join(
            [cell(base.get("anf-s"))] + [cell(r) for r in runs] + ["-", cell(base.get("oidn-high"))]) + " |")
    for name in SETS:
        for spp in (1, 4, 8):
            files = [RESULTS / "highspp" / f"{name}-8spp.json"] if spp == 8 else \
                [RESULTS / "long" / name / f"{w}-{spp}spp.json" for w in ("baseline", "wskpn-6e-6")]
            base = shipped(files)
            runs = [run_result(HERE / name / f"{r}-{spp}spp.json") for r in RUNS]
            if not any(runs):
                continue
            print(f"| {name} | {spp} | " + " | ".join(
                [cell(base.get("anf-s"))] + [cell(r) for r in runs]
                + [cell(base.get(k)) for _, k in SHIPPED[1:]]) + " |")


if __name__ == "__main__":
    main()
