#!/usr/bin/env bash
# Issue 15: the albedo history's weight. The shipped wskpn-6e weights under wskpn-6e-aa's rules
# with the albedo's [[accumulate]] weight changed. The spec's weight follows the frame's spp,
# spp / (spp + 4); tried beside it: a fixed alpha 0.2 (what the spec had first: it gained 0.58 dB
# at 1 spp on long-slow and lost 0.16 at 8) and spp / (spp + 8), on the sets where it can lose
# most (fast motion: ghosting) and gain most, at 1 and 8 spp, after 8 warm-up frames.
#
# Usage: bash docs/results/albedo-history/sweep.sh [SET...]
# Writes docs/results/albedo-history/<set>/sweep-<spp>spp.json. The committed ones were made
# when the spec was the fixed 0.2 (commit 04d8be4), with the variants K = 4 and K = 8; eval.sh
# at that commit made <set>/a02-<spp>spp.json (then named <spp>spp.json).
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=docs/results/albedo-history
tmp=/tmp/albedo-history
mkdir -p "$tmp"
sets=("$@")
[ ${#sets[@]} -gt 0 ] || sets=(long-slow long-fast heldout-room_window)
files=()
for variant in a02 k8; do
  # The spec's albedo entry is its last [[accumulate]], ending "history_spp = 4.0": a02 drops
  # that line (alpha 0.2 at every spp), k8 makes it 8. The name tells the rows apart.
  sed -e "s/^name = \"wskpn-6e-aa\"/name = \"wskpn-6e-aa-$variant\"/" models_spec/wskpn-6e-aa.toml \
    | awk -v v="$variant" '/^layer = "albedo"/ {albedo=1}
        albedo && /^history_spp = / {if (v == "k8") print "history_spp = 8.0"; next} {print}' \
    > "$tmp/wskpn-6e-aa-$variant.toml"
  [ "$(grep -c '^history_spp = ' "$tmp/wskpn-6e-aa-$variant.toml")" = "$([ $variant = a02 ] && echo 1 || echo 2)" ]
  [ -f "$tmp/wskpn-6e-aa-$variant.onnx" ] || mcdenoise export models/wskpn-6e.onnx --protocol-from "$tmp/wskpn-6e-aa-$variant.toml" \
    --out "$tmp/wskpn-6e-aa-$variant.onnx"
  files+=("$tmp/wskpn-6e-aa-$variant.onnx")
done
for set in "${sets[@]}"; do
  [ -f "data/$set/manifest.json" ] || { echo "sweep.sh: data/$set not rendered, skipped" >&2; continue; }
  mkdir -p "$out/$set"
  for spp in 1 8; do
    mcdenoise evaluate "${files[@]}" --no-oidn --data "data/$set" --spp $spp --warmup 8 \
      --threads "$(nproc)" --json "$out/$set/sweep-${spp}spp.json"
  done
done
