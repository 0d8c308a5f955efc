#!/usr/bin/env bash
# Issue 15's "every shipped model improves monotonically from 1 to 8 spp on stills": the first
# frame of every held-out sequence (no history), at 1, 2, 4 and 8 spp, every shipped model
# (models/*.onnx) and Open Image Denoise high, on the held-out sets (each rendered by its
# TestSet.render_args(), training/testsets.py, or docs/render-queue.sh; curves-test by
# docs/results/curves/commands.sh). A set not rendered is skipped.
# Usage: bash docs/results/stills-spp/commands.sh [SET...]   (default: all four below; the table is
# written from every set's results present)
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/stills-spp
all="curves-test long-slow heldout-room_window heldout-lamp_occluder"
for data in ${@:-$all}; do
  [ -f "data/$data/manifest.json" ] || { echo "stills-spp: data/$data not rendered, skipped" >&2; continue; }
  for spp in 1 2 4 8; do
    mcdenoise evaluate models/*.onnx --data "data/$data" --spp $spp --stills --json "$out/$data-$spp.json"
  done
done
python - "$out" $all <<'PY'
import json, sys, pathlib
out = pathlib.Path(sys.argv[1])
lines = ["# Stills (first frames, no history) at 1 / 2 / 4 / 8 spp", "",
         "Written by `docs/results/stills-spp/commands.sh`; PSNR dB (ANF Eq. 14). A model passes where",
         "each step up in spp scores higher.", ""]
for data in sys.argv[2:]:
    if not all((out / f"{data}-{s}.json").exists() for s in (1, 2, 4, 8)):
        continue
    res = {s: json.loads((out / f"{data}-{s}.json").read_text()) for s in (1, 2, 4, 8)}
    n = res[1]["_setup"]["sequences"]
    lines += [f"## data/{data} ({n} stills)", "", "| method | 1 | 2 | 4 | 8 | monotonic |", "|---|---:|---:|---:|---:|---|"]
    for m in (k for k in res[1] if k != "_setup"):
        p = [res[s][m]["psnr"] for s in (1, 2, 4, 8)]
        mono = all(b > a for a, b in zip(p, p[1:]))
        lines.append(f"| {m} | " + " | ".join(f"{v:.2f}" for v in p) + f" | {'yes' if mono else 'no'} |")
    lines.append("")
(out / "README.md").write_text("\n".join(lines))
print("\n".join(lines))
PY
