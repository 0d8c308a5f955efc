#!/usr/bin/env bash
# Issue 15: the fair peer of wskpn-6e-aa. Open Image Denoise high fed the albedo accumulated over
# frames exactly as the driver accumulates wskpn-6e-aa's (training.methods.AlbedoHistory: the
# driver's reprojection and consistency test, the spec's weight spp / (spp + 4)), on the sets and spp of eval.sh, after
# 8 warm-up frames. A gain of wskpn-6e-aa that OIDN also gets from the cleaner albedo is no
# gain over it.
#
# Usage: bash docs/results/albedo-history/peer.sh [SET...]
# Writes docs/results/albedo-history/<set>/peer-<spp>spp.json (with the noisy input's row). The
# committed peer-a02-<spp>spp.json were made at commit 3eef59f, when the weight was a fixed 0.2
# (the same as now at 1 spp).
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=docs/results/albedo-history
sets=("$@")
[ ${#sets[@]} -gt 0 ] || sets=(long-slow long-medium long-fast heldout-room_window heldout-lamp_occluder)
for set in "${sets[@]}"; do
  [ -f "data/$set/manifest.json" ] || { echo "peer.sh: data/$set not rendered, skipped" >&2; continue; }
  mkdir -p "$out/$set"
  for spp in 1 4 8; do
    mcdenoise evaluate oidn-high-aa --no-oidn --data "data/$set" --spp $spp --warmup 8 \
      --threads "$(nproc)" --json "$out/$set/peer-${spp}spp.json"
  done
done
