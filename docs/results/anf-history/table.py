"""table.md of docs/results/anf-history from its JSONs (commands.sh)."""
import json
from pathlib import Path

out = Path(__file__).parent


def cell(set_, spp, key, reset=False):
    f = out / f"{set_}-{spp}-{key}.json"
    if not f.exists():
        return "-"
    r = json.loads(f.read_text())
    name = [m for m in r if m.startswith("anf-s") and (m.endswith("(no history)") == reset)][0]
    a = r[name]["after_warmup"]
    return f"{a['psnr']:.2f} / {a['trmae']:.3f} / {a['wte']:.2f}"


print("# anf-s: the accumulation weight λ bounded by 1 - spp / (spp + K)\n")
print("Written by `docs/results/anf-history/commands.sh` (no retraining; the shipped weights). Each "
      "cell: PSNR dB / TRMAE / WTE after the warm-up frames (curves-test 2, the others 8). "
      "`reset`: the model reset before every frame; `unbounded`: as trained.\n")
for set_, spps, keys in (("curves-test", (1, 2, 4, 8), ("k0.5", "k1", "k2", "k4")),
                         ("long-slow", (1, 4), ("k0.5", "k1", "k2", "k4")),
                         ("heldout-room_window", (1, 4), ("bounded",)),
                         ("heldout-lamp_occluder", (1, 4), ("bounded",))):
    print(f"## {set_}\n")
    print("| spp | reset | unbounded | " + " | ".join(keys) + " |")
    print("|---:|---:|---:|" + "---:|" * len(keys))
    for spp in spps:
        print(f"| {spp} | {cell(set_, spp, 'unbounded', True)} | {cell(set_, spp, 'unbounded')} | "
              + " | ".join(cell(set_, spp, k) for k in keys) + " |")
    print()
