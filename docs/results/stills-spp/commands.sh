#!/usr/bin/env bash
# Issue 15's "every shipped model improves monotonically from 1 to 8 spp on stills": the first
# frame of every held-out sequence (no history), at 1, 2, 4 and 8 spp, every shipped model and
# Open Image Denoise high, on the two procedural held-out sets this machine has.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/stills-spp
models="models/wskpn-3.onnx models/wskpn-6.onnx models/nbg-2l-1g.onnx models/nbg-2l-3g.onnx models/anf-s.onnx"
for data in curves-test long-slow; do
  for spp in 1 2 4 8; do
    mcdenoise evaluate $models --data data/$data --spp $spp --stills --json $out/$data-$spp.json
  done
done
python - "$out" <<'PY'
import json, sys, pathlib
out = pathlib.Path(sys.argv[1])
lines = ["# Stills (first frames, no history) at 1 / 2 / 4 / 8 spp", "",
         "Written by `docs/results/stills-spp/commands.sh`; PSNR dB (ANF Eq. 14). A model passes where",
         "each step up in spp scores higher.", ""]
for data in ("curves-test", "long-slow"):
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
