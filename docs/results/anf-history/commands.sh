#!/usr/bin/env bash
# Issue 16 (and 15's "a history never worse than none"): anf-s's learned accumulation weight λ
# bounded by the driver's spp-aware rule, λ <= 1 - spp / (spp + K) (models_spec/anf-s.toml
# [[state]] embed: alpha / history_spp; training/models/anf.py). No retraining: the shipped
# weights, the bound fed as the `embed_weight` input. K is chosen on the procedural test sets
# (data/curves-test, seed 11, warm-up 2; data/long-slow, warm-up 8), then checked on the
# hand-made held-out scenes, which decide nothing. Writes <set>-<spp>-<setting>.json here.
# Data: docs/render-queue.sh (or each TestSet.render_args() in training/testsets.py).
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/anf-history
spec=${SPEC:-models_spec/anf-s.toml}
# the shipped file as trained, without the bound (the commit that shipped it)
base=/tmp/anf-s-unbounded.onnx
git show 9dc45fb:models/anf-s.onnx > "$base"
capped=/tmp/anf-s-bounded.onnx
mcdenoise export "$base" --out "$capped" --protocol-from "$spec"
score() {  # set warmup spp setting args...
  local set=$1 warm=$2 spp=$3 key=$4; shift 4
  [ -f "$out/$set-$spp-$key.json" ] || mcdenoise evaluate "$@" --data "data/$set" --spp "$spp" --warmup "$warm" \
    --no-oidn --json "$out/$set-$spp-$key.json" > /dev/null
}
for set_warm in "curves-test 2" "long-slow 8"; do
  read -r set warm <<< "$set_warm"
  spps="1 2 4 8"; [ "$set" = long-slow ] && spps="1 4"
  for spp in $spps; do
    score "$set" "$warm" "$spp" unbounded "$base" --no-history
    for k in ${KS:-0.5 1 2 4}; do score "$set" "$warm" "$spp" "k$k" "$capped" --history-spp "$k"; done
  done
done
# The check on scenes made by people (never tuned on): the file's own K against no bound.
for set in heldout-room_window heldout-lamp_occluder; do
  for spp in 1 4; do
    score "$set" 8 "$spp" unbounded "$base" --no-history
    score "$set" 8 "$spp" bounded "$capped"
  done
done
python docs/results/anf-history/table.py > docs/results/anf-history/table.md
