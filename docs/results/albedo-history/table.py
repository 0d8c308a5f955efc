"""The albedo history (issue 15) as markdown:

    python docs/results/albedo-history/table.py > docs/results/albedo-history/table.md

Reads only this folder's committed evaluations (``mcdenoise evaluate --json``):
<set>/<spp>spp.json (eval.sh: wskpn-6e as shipped, its weights under wskpn-6e-aa's rules,
Open Image Denoise high), <set>/a02-<spp>spp.json (the same when the spec's albedo weight was a
fixed 0.2, commit 04d8be4), <set>/peer-<spp>spp.json (peer.sh: Open Image Denoise high fed the
accumulated albedo; peer-a02-<spp>spp.json when that was at a fixed 0.2, commit 3eef59f), <set>/sweep-<spp>spp.json (sweep.sh: other albedo weights),
<set>/runs-<spp>spp.json (train.sh's A/B, scored by eval.sh with TAG=runs), <set>/s7-<spp>spp.json
(scale sitting 7, wskpn-6e-aa trained on the chain's shards: docs/results/scale/README.md, TAG=s7),
<set>/others-<spp>spp.json (others.sh: wskpn-3 and wskpn-6 as shipped and with the albedo history,
Open Image Denoise fast and fast-aa), <set>/nbg-<spp>spp.json (others.sh with BASES="nbg-2l-1g nbg-2l-3g":
the two shipped NBG files as shipped and with the albedo history).
PSNR dB on tonemapped radiance (ANF Eq. 14) / TRMAE (Eq. 16), with history, after 8 warm-up frames."""
from pathlib import Path

from mcdenoise.training.evaluate import load_results as load   # {method: after warm-up}, {} if missing

HERE = Path(__file__).resolve().parent
SETS = ("long-slow", "long-medium", "long-fast", "heldout-room_window", "heldout-lamp_occluder")
SPP = (1, 4, 8)
#: column -> the (file prefix, method key) that hold it, the first found wins
COLUMNS = {"wskpn-6e (shipped)": (("", "wskpn-6e"), ("a02-", "wskpn-6e")),
           "aa, alpha 0.2": (("a02-", "wskpn-6e-aa"), ("sweep-", "wskpn-6e-aa-a02")),
           "aa, K 4 (the spec)": (("", "wskpn-6e-aa"), ("sweep-", "wskpn-6e-aa-k4")),
           "aa, K 8": (("sweep-", "wskpn-6e-aa-k8"),),
           "A/B control wskpn-6e-ft": (("runs-", "wskpn-6e"),),
           "A/B wskpn-6e-aa trained": (("runs-", "wskpn-6e-aa"),),
           "wskpn-6e-aa, scale sitting 7": (("s7-", "wskpn-6e-aa"),),
           "oidn-high": (("", "oidn-high"), ("a02-", "oidn-high")),
           "oidn-high-aa, alpha 0.2": (("peer-a02-", "oidn-high-aa"),),
           "oidn-high-aa, K 4": (("peer-", "oidn-high-aa"),)}
#: the second table: the other shipped kernel-predicting models, zero-shot, and their fast peer
OTHERS = {m: (("others-", m),) for m in ("wskpn-3", "wskpn-3-aa", "wskpn-6", "wskpn-6-aa", "oidn-fast", "oidn-fast-aa")}
#: the third: NBG, zero-shot
NBG = {m: (("nbg-", m),) for m in ("nbg-2l-1g", "nbg-2l-1g-aa", "nbg-2l-3g", "nbg-2l-3g-aa")}


def cell(r) -> str:
    return "-" if r is None else f"{r['psnr']:.2f} / {r['trmae']:.3f}"


def table(columns: dict) -> None:
    files = {(s, p, spp): load(HERE / s / f"{p}{spp}spp.json")
             for s in SETS for p in {p for c in columns.values() for p, _ in c} for spp in SPP}

    def result(s, col, spp):
        return next((files[(s, p, spp)][k] for p, k in columns[col] if k in files[(s, p, spp)]), None)

    cols = [c for c in columns if any(result(s, c, spp) for s in SETS for spp in SPP)]
    print("| set | spp | " + " | ".join(cols) + " |")
    print("|---|---:|" + "---:|" * len(cols))
    for s in SETS:
        for spp in SPP:
            row = [cell(result(s, c, spp)) for c in cols]
            if any(x != "-" for x in row):
                print(f"| {s} | {spp} | " + " | ".join(row) + " |")


def main() -> None:
    print("# The albedo history (issue 15)\n")
    print("Made by `python docs/results/albedo-history/table.py` from the evaluations of eval.sh, peer.sh,")
    print("sweep.sh (and train.sh's runs, scored by eval.sh). PSNR dB / TRMAE, with history, after 8 warm-up")
    print("frames. \"aa\": the shipped wskpn-6e weights, the driver also accumulating the albedo (spec")
    print("wskpn-6e-aa) at a fixed alpha 0.2, or at spp / (spp + K).\n")
    table(COLUMNS)
    if any((HERE / s / f"others-{spp}spp.json").exists() for s in SETS for spp in SPP):
        print("\n## The other shipped kernel-predicting models (others.sh)\n")
        print("Their shipped weights as shipped and with the albedo history (\"-aa\": their spec plus")
        print("wskpn-6e-aa's albedo entry, K 4), beside Open Image Denoise fast with the 1-spp albedo and the")
        print("accumulated one.\n")
        table(OTHERS)
    if any((HERE / s / f"nbg-{spp}spp.json").exists() for s in SETS for spp in SPP):
        print("\n## NBG (others.sh with BASES=\"nbg-2l-1g nbg-2l-3g\")\n")
        print("The shipped NBG files as shipped and with the same albedo entry (\"-aa\"), zero-shot: NBG")
        print("demodulates the colour by the albedo in its graph's temporal stage and re-modulates its output.\n")
        table(NBG)

if __name__ == "__main__":
    main()
