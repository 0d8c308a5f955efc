#!/usr/bin/env bash
# Issue 15: the albedo history's weight. The shipped wskpn-6e weights under wskpn-6e-aa's rules
# with the albedo's [[accumulate]] weight changed: a fixed alpha 0.2 (the spec's) loses 0.16 dB
# at 8 spp on long-slow while it gains 0.58 at 1 spp, so a weight that follows the frame's spp
# (spp / (spp + K), the colour's rule) is tried with K = 4 and 8, on the sets where it can
# lose most (fast motion: ghosting) and gain most, at 1 and 8 spp, after 8 warm-up frames.
#
# Usage: bash docs/results/albedo-history/sweep.sh [SET...]
# Writes docs/results/albedo-history/<set>/sweep-<spp>spp.json.
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=docs/results/albedo-history
tmp=/tmp/albedo-history
mkdir -p "$tmp"
sets=("$@")
[ ${#sets[@]} -gt 0 ] || sets=(long-slow long-fast heldout-room_window)
files=()
for k in 4 8; do
  # The spec's albedo entry is its last [[accumulate]]: "alpha = 0.2" then nothing; the rule
  # spp / (spp + K) is "history_spp = K" after it. The name tells the rows apart.
  sed -e "s/^name = \"wskpn-6e-aa\"/name = \"wskpn-6e-aa-k$k\"/" models_spec/wskpn-6e-aa.toml \
    | awk -v k="$k" '{print} /^layer = "albedo"/ {albedo=1} albedo && /^alpha = / {print "history_spp = " k; albedo=0}' \
    > "$tmp/wskpn-6e-aa-k$k.toml"
  grep -q "^history_spp = $k\$" "$tmp/wskpn-6e-aa-k$k.toml"
  [ -f "$tmp/wskpn-6e-aa-k$k.onnx" ] || mcdenoise export models/wskpn-6e.onnx --protocol-from "$tmp/wskpn-6e-aa-k$k.toml" \
    --out "$tmp/wskpn-6e-aa-k$k.onnx"
  files+=("$tmp/wskpn-6e-aa-k$k.onnx")
done
for set in "${sets[@]}"; do
  [ -f "data/$set/manifest.json" ] || { echo "sweep.sh: data/$set not rendered, skipped" >&2; continue; }
  mkdir -p "$out/$set"
  for spp in 1 8; do
    mcdenoise evaluate "${files[@]}" --no-oidn --data "data/$set" --spp $spp --warmup 8 \
      --threads "$(nproc)" --json "$out/$set/sweep-${spp}spp.json"
  done
done
