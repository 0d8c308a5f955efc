#!/usr/bin/env bash
# Issue 15: the albedo history for the other shipped kernel-predicting models. wskpn-3 and
# wskpn-6 demodulate by the albedo and read it as an input, as wskpn-6e does; their shipped
# weights are driven under their own spec plus wskpn-6e-aa's albedo entry (weight spp / (spp + 4)),
# no retraining, beside the same files as shipped and Open Image Denoise fast and fast-aa (the
# peer wskpn-3 is measured against: issue 15 asks for it within 1 dB of oidn-fast), through the
# driver with history, after 8 warm-up frames, at 1, 4 and 8 spp.
#
# Usage: bash docs/results/albedo-history/others.sh [SET...]   (default: long-slow heldout-lamp_occluder)
# Writes docs/results/albedo-history/<set>/others-<spp>spp.json (keys wskpn-3, wskpn-3-aa, wskpn-6,
# wskpn-6-aa, oidn-fast, oidn-fast-aa); table.py reads them.
# NBG (it also demodulates by the albedo, inside its graph's temporal stage):
#   BASES="nbg-2l-1g nbg-2l-3g" PEERS= TAG=nbg bash docs/results/albedo-history/others.sh SET...
# writes <set>/nbg-<spp>spp.json (keys nbg-2l-1g, nbg-2l-1g-aa, nbg-2l-3g, nbg-2l-3g-aa).
set -euo pipefail
cd "$(dirname "$0")/../../.."
sets=("${@:-long-slow}")
[ $# -gt 0 ] || sets+=(heldout-lamp_occluder)
out=docs/results/albedo-history tmp=/tmp/albedo-history
mkdir -p "$tmp"
files=()
read -r -a bases <<< "${BASES-wskpn-3 wskpn-6}"
read -r -a peers <<< "${PEERS-oidn-fast oidn-fast-aa}"
for m in "${bases[@]}"; do
  if [ -f "models_spec/$m-aa.toml" ]; then   # shipped since (wskpn-3-aa): its own spec file
    mcdenoise export "models/$m.onnx" --protocol-from "models_spec/$m-aa.toml" --out "$tmp/$m-aa.onnx"
    files+=("models/$m.onnx" "$tmp/$m-aa.onnx")
    continue
  fi
  # The model's own spec, renamed, plus wskpn-6e-aa's albedo entry (its last [[accumulate]]).
  { sed -e "s/^name = \"$m\"/name = \"$m-aa\"/" "models_spec/$m.toml"
    awk '/^\[\[accumulate\]\]/ {n++} n == 2 && /^\[params\]/ {exit} n == 2 {print}' models_spec/wskpn-6e-aa.toml
  } > "$tmp/$m-aa.toml"
  grep -q '^layer = "albedo"' "$tmp/$m-aa.toml"
  mcdenoise export "models/$m.onnx" --protocol-from "$tmp/$m-aa.toml" --out "$tmp/$m-aa.onnx"
  files+=("models/$m.onnx" "$tmp/$m-aa.onnx")
done
for set in "${sets[@]}"; do
  [ -f "data/$set/manifest.json" ] || { echo "others.sh: data/$set not rendered, skipped" >&2; continue; }
  mkdir -p "$out/$set"
  for spp in 1 4 8; do
    mcdenoise evaluate "${files[@]}" ${peers[@]+"${peers[@]}"} --no-oidn --data "data/$set" --spp $spp \
      --warmup 8 --threads "$(nproc)" --json "$out/$set/${TAG:-others}-${spp}spp.json"
  done
done
