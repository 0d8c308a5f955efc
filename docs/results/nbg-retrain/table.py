"""The NBG retraining (issue 15) as markdown:

    python docs/results/nbg-retrain/table.py > docs/results/nbg-retrain/table.md

Reads this folder's evaluations (eval.sh, ``mcdenoise evaluate --json``): <set>/[ft-|lr5e-5-]<spp>spp.json
(sequences with history, after 8 warm-up frames: PSNR dB on tonemapped radiance, ANF Eq. 14 /
TRMAE, Eq. 16; ft-: train.sh's runs, nf-: the same without outliers (TAG=nf FIREFLIES=0), lr5e-5-: the third arm, scored by hand: README; <arm>-: arms.sh) and <set>/[ft-|lr5e-5-]stills-<spp>spp.json (first frames, no history: PSNR). For context, the
peers' sequence scores committed in docs/results/albedo-history (the same set, rendered by the same
command on an earlier machine): wskpn-3-aa and Open Image Denoise fast and high."""
from pathlib import Path

from mcdenoise.training.evaluate import load_results

HERE = Path(__file__).resolve().parent
AH = HERE.parent / "albedo-history"
SETS = ("long-slow", "long-medium", "long-fast", "heldout-room_window", "heldout-lamp_occluder", "curves-test")
#: column -> (file prefix, method key): evaluate names a method by its spec, so the retrained
#: files' scores are in the ft- files under the same keys
MODELS = {"nbg-2l-1g-aa": ("", "nbg-2l-1g-aa"), "nbg-2l-1g-aa-ft": ("ft-", "nbg-2l-1g-aa"),
          "nbg-2l-1g-aa-lr5e-5": ("lr5e-5-", "nbg-2l-1g-aa"),
          "nbg-2l-1g-aa-nf": ("nf-", "nbg-2l-1g-aa"),
          "nbg-2l-3g-aa": ("", "nbg-2l-3g-aa"), "nbg-2l-3g-aa-ft": ("ft-", "nbg-2l-3g-aa"),
          "nbg-2l-3g-aa-nf": ("nf-", "nbg-2l-3g-aa")}
#: arms.sh's one-factor arms from nbg-2l-1g-aa, each against the shipped file and the full fine-tune
#: (row -> file prefix; the method key is nbg-2l-1g-aa in every file)
ARMS = {"shipped nbg-2l-1g-aa": "", "ft (all four changes)": "ft-", "arm orig (none)": "orig-",
        "arm spp1 (spp 1 only)": "spp1-", "arm win2 (2-frame windows)": "win2-",
        "arm notemp (no temporal term)": "notemp-", "arm nofire (no outliers)": "nofire-",
        "arm fixed (ft, the temporal term fixed)": "fixed-"}
PEERS = {"wskpn-3-aa": "others-", "oidn-fast": "others-", "oidn-high": ""}


def main() -> None:
    print("## Sequences with history, after 8 warm-up frames (curves-test: 4): PSNR dB / TRMAE\n")
    cols = list(MODELS) + [f"{p} (earlier render)" for p in PEERS]
    print("| set | spp | " + " | ".join(cols) + " |")
    print("|---|---:|" + "---:|" * len(cols))
    for s in SETS:
        for spp in (1, 4, 8):
            ours = {m: load_results(HERE / s / f"{pre}{spp}spp.json").get(k) for m, (pre, k) in MODELS.items()}
            if not any(ours.values()):
                continue
            cells = list(ours.values())
            cells += [load_results(AH / s / f"{pre}{spp}spp.json").get(p) for p, pre in PEERS.items()]
            print(f"| {s} | {spp} | " + " | ".join("-" if r is None else f"{r['psnr']:.2f} / {r['trmae']:.3f}"
                                                    for r in cells) + " |")
    print("\n## Stills (first frames, no history): PSNR dB at 1 / 2 / 4 / 8 spp\n")
    print("| set | model | 1 | 2 | 4 | 8 | monotonic |")
    print("|---|---|---:|---:|---:|---:|---|")
    for s in SETS:
        for m, (pre, k) in MODELS.items():
            res = [load_results(HERE / s / f"{pre}stills-{spp}spp.json", after_warmup=False).get(k) for spp in (1, 2, 4, 8)]
            if not all(res):
                continue
            p = [r["psnr"] for r in res]
            mono = all(b > a for a, b in zip(p, p[1:]))
            print(f"| {s} | {m} | " + " | ".join(f"{v:.2f}" for v in p) + f" | {'yes' if mono else 'no'} |")

    arms()


def arms() -> None:
    """One row per arm: sequences (with history) at 1 / 4 / 8 spp and 1-spp stills, per set."""
    sets = [s for s in SETS if (HERE / s / "orig-1spp.json").exists() or (HERE / s / "spp1-1spp.json").exists()]
    if not sets:
        return
    print("\n## One factor of the fine-tune's recipe at a time (arms.sh), nbg-2l-1g-aa\n")
    print("Sequences with history, PSNR dB / TRMAE at 1, 4, 8 spp; then PSNR of 1-spp and 8-spp stills.\n")
    for s in sets:
        print(f"### {s}\n")
        print("| run | 1 spp | 4 spp | 8 spp | still 1 spp | still 8 spp |")
        print("|---|---:|---:|---:|---:|---:|")
        for name, pre in ARMS.items():
            seq = [load_results(HERE / s / f"{pre}{spp}spp.json").get("nbg-2l-1g-aa") for spp in (1, 4, 8)]
            st = [load_results(HERE / s / f"{pre}stills-{spp}spp.json", after_warmup=False).get("nbg-2l-1g-aa")
                  for spp in (1, 8)]
            if not any(seq + st):
                continue
            cells = ["-" if r is None else f"{r['psnr']:.2f} / {r['trmae']:.3f}" for r in seq]
            cells += ["-" if r is None else f"{r['psnr']:.2f}" for r in st]
            print(f"| {name} | " + " | ".join(cells) + " |")
        print()


if __name__ == "__main__":
    main()
