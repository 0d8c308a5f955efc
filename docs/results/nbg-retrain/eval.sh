#!/usr/bin/env bash
# Issue 15: the retrained NBG files (train.sh) against the zero-shot -aa files they started from,
# on the sets this machine has rendered (each by its TestSet.render_args(), training/testsets.py;
# a set not rendered is skipped). Sequences through the driver with history, after 8 warm-up
# frames, at 1, 4 and 8 spp; stills (first frames, no history) at 1, 2, 4 and 8 spp.
# Usage: [TAG=ft] [SHIPPED=0] bash docs/results/nbg-retrain/eval.sh [SET...]   (TAG: train.sh's; SHIPPED=0
# skips the zero-shot starting files; default sets: the five long and hand-made ones;
# curves-test, 4 held-out procedural scenes x 8 frames of 128x128 (docs/results/curves/data.sh), with WARMUP=4)
# Writes docs/results/nbg-retrain/<set>/[<TAG>-]<spp>spp.json and [<TAG>-]stills-<spp>spp.json (<TAG>-:
# the retrained files); table.py reads them.
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=docs/results/nbg-retrain tmp=/tmp/nbg-retrain tag=${TAG:-ft}
sets=("${@:-long-slow long-medium long-fast heldout-room_window heldout-lamp_occluder}")
[ $# -gt 0 ] || read -r -a sets <<< "${sets[0]}"
for spec in nbg-2l-1g-aa nbg-2l-3g-aa; do
  [ -f "$tmp/$spec-$tag.onnx" ] || mcdenoise export "$out/$spec-$tag" --out "$tmp/$spec-$tag.onnx"
done
# evaluate names a method by its spec, so the starting (zero-shot, common.sh) and the retrained files
# go in separate runs.
. "$out/common.sh"
start=("$(zero_shot nbg-2l-1g-aa)" "$(zero_shot nbg-2l-3g-aa)")
retrained=("$tmp/nbg-2l-1g-aa-$tag.onnx" "$tmp/nbg-2l-3g-aa-$tag.onnx")
for set in "${sets[@]}"; do
  [ -f "data/$set/manifest.json" ] || { echo "eval.sh: data/$set not rendered, skipped" >&2; continue; }
  [ "${SHIPPED:-1}" = 1 ] && score "$set" "" "${start[@]}"
  score "$set" "$tag-" "${retrained[@]}"
done
