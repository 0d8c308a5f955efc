#!/usr/bin/env bash
# Scores train.sh's two runs (anf-s-ft, anf-sd) through the runtime API, with history:
#   - data/curves-test sequences at 1 and 4 spp (warm-up 2, as the anf-s card), and the stills
#     (first frames) of curves-test and long-slow at 1, 2, 4, 8 spp (issue 15: every model
#     improves monotonically with spp; the shipped anf-s's are in docs/results/stills-spp);
#   - held-out sets (never trained on) at 1, 4, 8 spp after 8 warm-up frames.
# Usage: bash docs/results/anf-demod/score.sh [RUN...]   (default: both runs)
#   SETS="..." held-out sets (default: long-slow heldout-room_window heldout-lamp_occluder, those
#   rendered under data/; docs/render-queue.sh renders them); SPPS="..." their spp (default 1 4 8).
# Writes docs/results/anf-demod/<run>/{curves-test,stills-<set>}-<spp>spp.json and
# docs/results/anf-demod/<set>/<run>-<spp>spp.json; python docs/results/anf-demod/table.py makes table.md.
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=docs/results/anf-demod
runs=("$@"); [ ${#runs[@]} -gt 0 ] || runs=("$out/anf-s-ft" "$out/anf-sd")
for r in "${runs[@]}"; do
  name=$(basename "$r")
  f="/tmp/$name.onnx"
  mcdenoise export "$r" --out "$f"
  for spp in 1 4; do
    mcdenoise evaluate "$f" --no-oidn --data data/curves-test --spp $spp --warmup 2 --threads "$(nproc)" \
      --json "$r/curves-test-${spp}spp.json"
  done
  for set in curves-test long-slow; do
    [ -f "data/$set/manifest.json" ] || continue
    for spp in 1 2 4 8; do
      mcdenoise evaluate "$f" --no-oidn --data "data/$set" --spp $spp --stills --threads "$(nproc)" \
        --json "$r/stills-$set-${spp}spp.json"
    done
  done
  for set in ${SETS:-long-slow heldout-room_window heldout-lamp_occluder}; do
    [ -f "data/$set/manifest.json" ] || { echo "score.sh: data/$set not rendered, skipped" >&2; continue; }
    mkdir -p "$out/$set"
    for spp in ${SPPS:-1 4 8}; do
      mcdenoise evaluate "$f" --no-oidn --data "data/$set" --spp $spp --warmup 8 --threads "$(nproc)" \
        --json "$out/$set/$name-${spp}spp.json"
    done
  done
done
python "$out/table.py" > "$out/table.md"
