#!/usr/bin/env bash
# Issue 15, the history: the driver's colour-accumulation weight of the shipped WSKPN models
# (trained at a fixed 0.2), fixed against spp-aware (spp / (spp + K)), against no accumulation
# (weight 1: the model reset before every frame, as WSKPN keeps no other state). No retraining:
# only the driver's weight changes. data/long-slow: training/testsets.py LONG_SEQUENCES["slow"]
# (the bench renders it; or data/render-long.sh). Writes <spp>-<setting>.json and table.md here.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/history-spp
models="models/wskpn-6.onnx models/wskpn-3.onnx"
for spp in 1 2 4 8; do
  mcdenoise evaluate $models --data data/long-slow --spp $spp --warmup 8 --no-oidn --alpha 0.2 --json $out/$spp-fixed0.2.json
  mcdenoise evaluate $models --data data/long-slow --spp $spp --warmup 8 --no-oidn --alpha 1 --json $out/$spp-none.json
  for k in 0.5 1 2; do
    mcdenoise evaluate $models --data data/long-slow --spp $spp --warmup 8 --no-oidn --history-spp $k --json $out/$spp-k$k.json
  done
done
python - "$out" <<'PY'
import json, sys, pathlib
out = pathlib.Path(sys.argv[1])
settings = [("none", "none (weight 1)"), ("fixed0.2", "fixed 0.2 (trained)"), ("k0.5", "spp/(spp+0.5)"),
            ("k1", "spp/(spp+1)"), ("k2", "spp/(spp+2)")]
lines = ["# The driver's accumulation weight, shipped WSKPN models on data/long-slow", "",
         "Written by `docs/results/history-spp/commands.sh`. PSNR dB after the 8 warm-up frames, then WTE "
         "(1 = as steady as the reference along the true motion; below 1 = smoother, i.e. lag).", ""]
for model in ("wskpn-6", "wskpn-3"):
    lines += [f"## {model}", "", "| weight | " + " | ".join(f"{s} spp" for s in (1, 2, 4, 8)) + " |",
              "|---|" + "---:|" * 4]
    for key, label in settings:
        cells = []
        for spp in (1, 2, 4, 8):
            a = json.loads((out / f"{spp}-{key}.json").read_text())[model]["after_warmup"]
            cells.append(f"{a['psnr']:.2f}, WTE {a['wte']:.2f}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines.append("")
(out / "table.md").write_text("\n".join(lines))
print("\n".join(lines))
PY
# What the measurements above decided: the shipped files take the specs' spp-aware weight
# (models_spec/wskpn-*.toml: history_spp = 1), graph and weights unchanged.
mcdenoise export models/wskpn-3.onnx --out models/wskpn-3.onnx --protocol-from models_spec/wskpn-3.toml
mcdenoise export models/wskpn-6.onnx --out models/wskpn-6.onnx --protocol-from models_spec/wskpn-6.toml
# A second held-out set (data/curves-test: 4 procedural scenes x 8 frames at 128x128, seed 11,
# docs/results/curves/commands.sh renders it), after 2 warm-up frames; the files now carry the rule.
for spp in 1 4; do
  mcdenoise evaluate $models --data data/curves-test --spp $spp --warmup 2 --no-oidn --alpha 0.2 --json $out/curves-test-$spp-fixed0.2.json
  mcdenoise evaluate $models --data data/curves-test --spp $spp --warmup 2 --no-oidn --alpha 1 --json $out/curves-test-$spp-none.json
  mcdenoise evaluate $models --data data/curves-test --spp $spp --warmup 2 --no-oidn --json $out/curves-test-$spp-k1.json
done
# NBG: its state's blend weight became an input the driver feeds (models_spec/nbg-*.toml
# [[state]] alpha / history_spp); the shipped files exported again with their trained weights
# (from the files before this change: git show a42a236:models/nbg-2l-1g.onnx), then scored.
for m in nbg-2l-1g nbg-2l-3g; do
  mcdenoise export models/$m.onnx --out models/$m.onnx --protocol-from models_spec/$m.toml
done
for spp in 1 2 4 8; do
  mcdenoise evaluate models/nbg-2l-1g.onnx models/nbg-2l-3g.onnx --data data/long-slow --spp $spp --warmup 8 --no-oidn --json $out/nbg-$spp-k1.json
  mcdenoise evaluate models/nbg-2l-1g.onnx models/nbg-2l-3g.onnx --data data/long-slow --spp $spp --warmup 8 --no-oidn --alpha 0.2 --json $out/nbg-$spp-fixed0.2.json
  mcdenoise evaluate models/nbg-2l-1g.onnx models/nbg-2l-3g.onnx --data data/long-slow --spp $spp --warmup 8 --no-oidn --alpha 1 --json $out/nbg-$spp-none.json
done
