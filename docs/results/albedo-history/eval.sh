#!/usr/bin/env bash
# Issue 15: the shipped wskpn-6e driven with an accumulated albedo (spec wskpn-6e-aa: the
# driver accumulates the albedo layer as it does the colour), against the same file driven as
# shipped and Open Image Denoise high, through the driver with history, on the long sequences
# and the hand-made held-out scenes, at 1, 4 and 8 spp, after 8 warm-up frames.
#
# Usage: bash docs/results/albedo-history/eval.sh [SET...]
#   MODELS="FILE.onnx..." adds files (train.sh's exports); ZERO=0 skips the zero-shot file;
#   BASE=0 skips the shipped file and Open Image Denoise; TAG=NAME writes <set>/NAME-<spp>spp.json.
#   Writes docs/results/albedo-history/<set>/<spp>spp.json; table.py makes table.md. The committed
#   <set>/a02-<spp>spp.json are this script's output when the spec's albedo weight was a fixed 0.2
#   (commit 04d8be4); sweep.sh makes that variant now.
#   The train.sh A/B: ZERO=0 BASE=0 TAG=runs MODELS="/tmp/albedo-history/wskpn-6e-ft.onnx
#   /tmp/albedo-history/wskpn-6e-aa.onnx" bash docs/results/albedo-history/eval.sh
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=docs/results/albedo-history
sets=("$@")
[ ${#sets[@]} -gt 0 ] || sets=(long-slow long-medium long-fast heldout-room_window heldout-lamp_occluder)
zero=/tmp/albedo-history/wskpn-6e-aa0.onnx
mkdir -p /tmp/albedo-history
# The shipped weights, the history rules of models_spec/wskpn-6e-aa.toml: the graph is the same.
mcdenoise export models/wskpn-6e.onnx --protocol-from models_spec/wskpn-6e-aa.toml --out "$zero"
read -r -a extra <<< "${MODELS-}"
models=()
[ "${BASE:-1}" = 0 ] || models+=(models/wskpn-6e.onnx)
[ "${ZERO:-1}" = 0 ] || models+=("$zero")
base=(); [ "${BASE:-1}" != 0 ] || base=(--no-oidn)
tag=${TAG:+$TAG-}
for set in "${sets[@]}"; do
  [ -f "data/$set/manifest.json" ] || { echo "eval.sh: data/$set not rendered, skipped" >&2; continue; }
  mkdir -p "$out/$set"
  for spp in 1 4 8; do
    mcdenoise evaluate "${models[@]}" "${extra[@]}" "${base[@]}" --data "data/$set" --spp $spp --warmup 8 \
      --threads "$(nproc)" --json "$out/$set/${tag}${spp}spp.json"
  done
done
