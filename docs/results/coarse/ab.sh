#!/usr/bin/env bash
# Issue 15: does the coarse term (train --coarse-weight) give back the energy the wskpn-6e runs lose?
# docs/results/long/error_probe.txt: the scale chain's runs are 4-10% darker than the reference on the
# held-out lamp_occluder scene (the noisy input is not), and most of their gap to Open Image Denoise
# is at scales of 8 pixels and more. Two fine-tunes of one run, the same data, seed and steps (the
# scale sittings' recipe: spp 1-8, 8-frame windows, temporal term 0.25, fireflies 0.001, a 3e-4
# cosine), without and with the coarse term; each scored on curves-test (sequences, after 2 warm-up
# frames) and by the error probe on the two hand-made scenes and long-slow (brightness, error by scale).
# Usage (after a scale sitting rendered data/train-256; nothing else running):
#   bash docs/results/coarse/ab.sh INIT STEPS WEIGHT [SEQUENCES]
#   INIT: the run both arms start from; SEQUENCES: --max-sequences (default 60: reading every
#   frame of a sitting's shards takes longer than the arms' steps here). A run folder already
#   there is resumed, so the script continues across sessions.
set -euo pipefail
cd "$(dirname "$0")/../../.."
init=$1; steps=$2; weight=$3; seqs=${4:-60}
out=docs/results/coarse
mkdir -p "$out"
for w in 0 "$weight"; do
  run=$out/cw$w
  if [ -f "$run/config.json" ]; then
    mcdenoise train wskpn-6e --data data/train-256 --out "$run" --resume --steps "$steps" --threads "$(nproc)" --quiet
  else
    mcdenoise train wskpn-6e --data data/train-256 --init "$init" --out "$run" --spp 1 2 4 8 --window 8 \
      --temporal-weight 0.25 --steps "$steps" --lr 3e-4 --lr-schedule cosine --val-every "$steps" \
      --test data/curves-test --threads "$(nproc)" --fireflies 0.001 --max-sequences "$seqs" \
      --coarse-weight "$w" --quiet
  fi
done
for w in 0 "$weight"; do
  mcdenoise export "$out/cw$w" --out "/tmp/cw$w.onnx"
  for spp in 1 4; do
    mcdenoise evaluate "/tmp/cw$w.onnx" --no-oidn --data data/curves-test --spp $spp --warmup 2 \
      --json "$out/cw$w/curves-test-${spp}spp.json"
  done
done
: > "$out/probe-cw$weight.txt"
for set in heldout-lamp_occluder heldout-room_window long-slow; do
  for spp in 1 4; do
    cmd="python docs/results/long/error_probe.py noisy /tmp/cw0.onnx /tmp/cw$weight.onnx oidn-high --data data/$set --spp $spp --warmup 8"
    echo "\$ $cmd" >> "$out/probe-cw$weight.txt"
    $cmd --threads "$(nproc)" >> "$out/probe-cw$weight.txt"
    echo >> "$out/probe-cw$weight.txt"
  done
done
