#!/usr/bin/env bash
# Issue 15: does a multi-resolution kernel predictor close the coarse gap? wskpn-6e against
# wskpn-mr-e (models_spec/wskpn-mr-e.toml: the paper's MR U-net, with wskpn-6e's accumulation,
# emissive layer and albedo clamp, at 1.16x its FLOPs), both from scratch, on the same data with
# the same seed, steps and recipe (the scale sittings': spp 1-8, 8-frame windows, temporal term
# 0.25, coarse term 1, a cosine over STEPS), validated every VAL steps on curves-test, so the two
# learning curves are read side by side; then each scored on curves-test and by the error probe
# on the hand-made room (brightness, error by scale) where those sets are rendered.
# The arms train at once, one thread each (one per core of this 2-core VM): the same compute each.
# Usage (after rendering data/train-256 and data/curves-test; nothing else running):
#   bash docs/results/mr/ab.sh STEPS VAL [MINUTES]
#   A run folder already there is resumed, so the A/B continues across sessions.
set -euo pipefail
cd "$(dirname "$0")/../../.."
steps=$1; val=$2; minutes=${3:-600}
out=docs/results/mr
pids=()
for spec in wskpn-6e wskpn-mr-e; do
  run=$out/$spec
  if [ -f "$run/config.json" ]; then
    mcdenoise train "$spec" --data data/train-256 --out "$run" --resume --steps "$steps" --minutes "$minutes" \
      --threads 1 --cache-dir data/cache --quiet > "$out/$spec.log" 2>&1 &
  else
    mcdenoise train "$spec" --data data/train-256 --out "$run" --spp 1 2 4 8 --window 8 --temporal-weight 0.25 \
      --coarse-weight 1 --steps "$steps" --minutes "$minutes" --lr-schedule cosine --val-every "$val" \
      --test data/curves-test --threads 1 --seed 0 --cache-dir data/cache --quiet > "$out/$spec.log" 2>&1 &
  fi
  pids+=($!)
done
for p in "${pids[@]}"; do wait "$p"; done
for spec in wskpn-6e wskpn-mr-e; do
  mcdenoise export "$out/$spec" --out "/tmp/ab-$spec.onnx"
  for spp in 1 4; do
    mcdenoise evaluate "/tmp/ab-$spec.onnx" --no-oidn --data data/curves-test --spp $spp --warmup 2 \
      --threads "$(nproc)" --json "$out/$spec/curves-test-${spp}spp.json"
  done
  for spp in 1 2 4 8; do    # issue 15: every model better with more samples
    mcdenoise evaluate "/tmp/ab-$spec.onnx" --no-oidn --data data/curves-test --spp $spp --stills \
      --threads "$(nproc)" --json "$out/$spec/stills-curves-test-${spp}spp.json"
  done
done
: > "$out/probe.txt"
for set in heldout-room_window heldout-lamp_occluder long-slow; do
  [ -f "data/$set/manifest.json" ] || continue
  for spp in 1 4; do
    for spec in wskpn-6e wskpn-mr-e; do    # PSNR and TRMAE as docs/results/long scores them
      mcdenoise evaluate "/tmp/ab-$spec.onnx" --no-oidn --data "data/$set" --spp $spp --warmup 8 --no-history \
        --threads "$(nproc)" --json "$out/$spec/$set-${spp}spp.json"
    done
    cmd="python docs/results/long/error_probe.py noisy /tmp/ab-wskpn-6e.onnx /tmp/ab-wskpn-mr-e.onnx oidn-high --data data/$set --spp $spp --warmup 8"
    echo "\$ $cmd" >> "$out/probe.txt"
    $cmd --threads "$(nproc)" >> "$out/probe.txt"
    echo >> "$out/probe.txt"
  done
done
