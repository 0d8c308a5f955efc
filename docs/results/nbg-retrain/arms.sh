#!/usr/bin/env bash
# Issue 15: why did the NBG fine-tune (train.sh) lose? One factor of its recipe at a time, each arm
# from the same start (the zero-shot nbg-2l-1g-aa file, common.sh; models/nbg-2l-1g-aa.onnx is that file), on the same data (data/nbg-train), steps, rate and
# seed as nbg-2l-1g-aa-ft, so an arm that keeps the shipped file's 1-spp score names the cause:
#   spp1     --spp 1                 (ft: spp drawn from 1, 2, 4, 8)
#   win2     --window 2              (ft: 8-frame windows; the loss sees the history-free frame 1/8 as often)
#   notemp   --temporal-weight 0     (ft: 0.25)
#   nofire   --fireflies 0           (ft: 0.001)
#   orig     all four back to the shipped file's own recipe (spp 1, 2-frame windows, no temporal term,
#            no outliers): new data and a fresh Adam only
#   fixed    ft's flags exactly, on the code after the temporal term's fix for l1_gamma (training/train.py
#            _l1_gamma_differences, 2026-12-07): every other arm with a temporal term ran before it
# Usage: bash docs/results/nbg-retrain/arms.sh train [ARM...]     (two at a time, one thread each)
#        bash docs/results/nbg-retrain/arms.sh eval SET [ARM...]  (WARMUP=4 for curves-test)
# Writes docs/results/nbg-retrain/arm-<arm>/ (run folder, small: commit it), arm-<arm>.log,
# /tmp/nbg-retrain/arm-<arm>.onnx, and <set>/<arm>-[stills-]<spp>spp.json for table.py.
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=docs/results/nbg-retrain tmp=/tmp/nbg-retrain spec=nbg-2l-1g-aa
mkdir -p "$tmp"
declare -A ARM=(
  [spp1]="--spp 1 --window 8 --temporal-weight 0.25 --fireflies 0.001"
  [win2]="--spp 1 2 4 8 --window 2 --temporal-weight 0.25 --fireflies 0.001"
  [notemp]="--spp 1 2 4 8 --window 8 --temporal-weight 0 --fireflies 0.001"
  [nofire]="--spp 1 2 4 8 --window 8 --temporal-weight 0.25 --fireflies 0"
  [orig]="--spp 1 --window 2 --temporal-weight 0 --fireflies 0"
  [fixed]="--spp 1 2 4 8 --window 8 --temporal-weight 0.25 --fireflies 0.001"
)
ALL="spp1 orig win2 notemp nofire fixed"

train_arm() {
  local arm=$1 run="$out/arm-$1" resume
  [ -n "${ARM[$arm]:-}" ] || { echo "arms.sh: no arm '$arm' (arms: $ALL)" >&2; return 2; }
  if [ -f "$run/checkpoint.pt" ] && ! grep -q '"final": true' "$run/metrics.jsonl" 2>/dev/null; then
    resume="--resume"
  elif [ -f "$run/checkpoint.pt" ]; then
    echo "arms.sh: $arm finished"; return 0
  else
    resume="--init $(zero_shot $spec)"
  fi
  # shellcheck disable=SC2086  # the arm's flags are words
  mcdenoise train "$spec" --data data/nbg-train --out "$run" $resume ${ARM[$arm]} \
    --steps "${STEPS:-1200}" --lr 3e-4 --lr-schedule cosine --minutes "${MINUTES:-40}" --val-every 400 \
    --threads 1 --seed 12 --quiet >> "$run.log" 2>&1
  mcdenoise export "$run" --out "$tmp/arm-$arm.onnx"
}

. "$out/common.sh"
eval_arm() {
  local set=$1 arm=$2 file="$tmp/arm-$2.onnx"
  [ -f "$file" ] || mcdenoise export "$out/arm-$arm" --out "$file"
  score "$set" "$arm-" "$file"
}

case "${1:-}" in
  train)
    shift; arms=("${@:-$ALL}"); [ $# -gt 0 ] || read -r -a arms <<< "$ALL"
    [ -f data/nbg-train/manifest.json ] || { echo "arms.sh: data/nbg-train missing: run train.sh first" >&2; exit 2; }
    export -f train_arm zero_shot; export out tmp spec ALL
    for a in "${arms[@]}"; do echo "$a"; done | \
      xargs -P 2 -I{} bash -c "$(declare -p ARM); train_arm {}" ;;
  eval)
    set_=${2:?arms.sh eval SET [ARM...]}; shift 2; arms=("${@:-$ALL}"); [ $# -gt 0 ] || read -r -a arms <<< "$ALL"
    [ -f "data/$set_/manifest.json" ] || { echo "arms.sh: data/$set_ not rendered" >&2; exit 2; }
    for a in "${arms[@]}"; do eval_arm "$set_" "$a"; done ;;
  *) echo "usage: arms.sh train [ARM...] | arms.sh eval SET [ARM...]" >&2; exit 2 ;;
esac
