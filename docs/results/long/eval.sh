#!/usr/bin/env bash
# Issue 15 section 1: every shipped model, the scale sittings' runs, our SVGF-style filter and
# Open Image Denoise on the long test sequences and the hand-made held-out scenes, as a
# real-time user sees them: through the driver with history, scored over all frames and after
# 8 warm-up frames (the bench's LONG_WARMUP), at 1 and 4 spp (the bench's LONG_SPP); every model
# also reset before each frame ("(no history)"), so what each history earns is read off.
#
# Usage: bash docs/results/long/eval.sh [SET...]   (default: every set whose folder exists;
#   render them with docs/render-queue.sh, or one by one with the commands testsets.py prints)
#   RUNS="FOLDER..." scores those run folders (default: every scale sitting's run in the table);
#   BASELINE=0 skips the shipped models, SVGF and Open Image Denoise (one new run costs minutes
#   a set; the baseline 10-20).
# Sets: long-slow long-medium long-fast heldout-room_window heldout-lamp_occluder.
# Writes docs/results/long/<set>/<who>-<spp>spp.json (who: "baseline", or a run folder's name,
# because two runs of one spec share a model name); table.py makes table.md from them.
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=docs/results/long
sets=("$@")
[ ${#sets[@]} -gt 0 ] || sets=(long-slow long-medium long-fast heldout-room_window heldout-lamp_occluder)
read -r -a runs <<< "${RUNS-docs/results/scale/wskpn-6e-clamp-1 docs/results/scale/wskpn-6e-2 docs/results/scale/wskpn-6e-3 docs/results/scale/wskpn-6e-5 docs/results/scale/wskpn-6e-6}"
for r in "${runs[@]}"; do
  [ -f "/tmp/$(basename "$r").onnx" ] || mcdenoise export "$r" --out "/tmp/$(basename "$r").onnx"
done
for set in "${sets[@]}"; do
  [ -f "data/$set/manifest.json" ] || { echo "eval.sh: data/$set not rendered, skipped" >&2; continue; }
  mkdir -p "$out/$set"
  # render --check-references: two independent references of each sequence's first frame
  [ ! -f "data/$set/reference_check.json" ] || cp "data/$set/reference_check.json" "$out/$set/"
  for spp in 1 4; do
    [ "${BASELINE:-1}" = 0 ] || mcdenoise evaluate noisy oidn-fast svgf models/wskpn-6.onnx models/wskpn-3.onnx models/nbg-2l-3g.onnx \
      models/anf-s.onnx models/ndle-s.onnx --data "data/$set" --spp $spp --warmup 8 --threads "$(nproc)" --no-history \
      --json "$out/$set/baseline-${spp}spp.json"
    for r in "${runs[@]}"; do
      mcdenoise evaluate "/tmp/$(basename "$r").onnx" --no-oidn --data "data/$set" --spp $spp --warmup 8 --no-history \
        --threads "$(nproc)" --json "$out/$set/$(basename "$r")-${spp}spp.json"
    done
  done
done
python "$out/table.py" > "$out/table.md"
