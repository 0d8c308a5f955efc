#!/usr/bin/env bash
# Issue 15: the shipped wskpn-6e driven with an accumulated albedo (spec wskpn-6e-aa: the
# driver accumulates the albedo layer as it does the colour), against the same file driven as
# shipped and Open Image Denoise high, through the driver with history, on the long sequences
# and the hand-made held-out scenes, at 1, 4 and 8 spp, after 8 warm-up frames.
#
# Usage: bash docs/results/albedo-history/eval.sh [SET...]
#   MODELS="FILE.onnx..." adds files (a retrained wskpn-6e-aa run's export); ZERO=0 skips the
#   zero-shot file. Writes docs/results/albedo-history/<set>/<spp>spp.json; table.py makes table.md.
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=docs/results/albedo-history
sets=("$@")
[ ${#sets[@]} -gt 0 ] || sets=(long-slow long-medium long-fast heldout-room_window heldout-lamp_occluder)
zero=/tmp/albedo-history/wskpn-6e-aa0.onnx
mkdir -p /tmp/albedo-history
# The shipped weights, the history rules of models_spec/wskpn-6e-aa.toml: the graph is the same.
[ -f "$zero" ] || mcdenoise export models/wskpn-6e.onnx --protocol-from models_spec/wskpn-6e-aa.toml --out "$zero"
read -r -a extra <<< "${MODELS-}"
models=(models/wskpn-6e.onnx)
[ "${ZERO:-1}" = 0 ] || models+=("$zero")
for set in "${sets[@]}"; do
  [ -f "data/$set/manifest.json" ] || { echo "eval.sh: data/$set not rendered, skipped" >&2; continue; }
  mkdir -p "$out/$set"
  for spp in 1 4 8; do
    mcdenoise evaluate "${models[@]}" "${extra[@]}" --data "data/$set" --spp $spp --warmup 8 \
      --threads "$(nproc)" --json "$out/$set/${spp}spp.json"
  done
done
