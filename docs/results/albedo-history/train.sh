#!/usr/bin/env bash
# Issue 15: does training with the albedo history add to what it gives the shipped weights?
# An A/B from the shipped wskpn-6e run (docs/results/scale/wskpn-6e-6), on the same data, the
# same steps and schedule, one arm after the other on every core:
#   wskpn-6e-ft  wskpn-6e trained on (the control: what more steps on this data alone buy);
#   wskpn-6e-aa  wskpn-6e-aa (the driver, and so the trainer's unroll, also accumulates the
#                albedo) started from the same weights (--init takes a run of another spec of
#                its type).
# The chain's last sitting's settings (spp 1 2 4 8, 8-frame windows, temporal weight 0.25,
# fireflies 0.001), a lower peak rate (a fine-tune) on a cosine planned over STEPS, which
# both arms finish inside MINUTES; a new seed, so the crops are new.
# Usage: [STEPS=1200] bash docs/results/albedo-history/train.sh MINUTES
# Data: data/curves-train (24 scenes, 128x128; not the chain's 256x256 shards, which this machine
# no longer has), data/curves-test for the validation curve; rendered here if missing (about 12
# minutes with --workers 2 on a 2-core VM). The decoded frames are shared in one --cache-dir.
# Writes docs/results/albedo-history/<run> (small: commit them) and <run>.log; score with
# ZERO=0 BASE=0 TAG=runs MODELS="/tmp/albedo-history/wskpn-6e-ft.onnx /tmp/albedo-history/wskpn-6e-aa.onnx" eval.sh
set -euo pipefail
cd "$(dirname "$0")/../../.."
minutes=$1
out=docs/results/albedo-history
bash docs/results/curves/data.sh
mkdir -p /tmp/albedo-history
for pair in "wskpn-6e-aa wskpn-6e-aa" "wskpn-6e wskpn-6e-ft"; do
  read -r spec run <<< "$pair"
  [ -f "$out/$run/checkpoint.pt" ] && [ -n "$(grep '"final": true' "$out/$run/metrics.jsonl" 2>/dev/null)" ] || \
    mcdenoise train "$spec" --data data/curves-train --out "$out/$run" --init docs/results/scale/wskpn-6e-6 \
      --spp 1 2 4 8 --window 8 --temporal-weight 0.25 --fireflies 0.001 --steps "${STEPS:-1200}" --lr 2e-4 \
      --lr-schedule cosine --minutes "$minutes" --val-every "${VAL_EVERY:-400}" --test data/curves-test \
      --threads "$(nproc)" --seed 31 --cache-dir /tmp/albedo-history/cache --quiet > "$out/$run.log" 2>&1
  mcdenoise export "$out/$run" --out "/tmp/albedo-history/$run.onnx"
done
echo "trained: $out/wskpn-6e-aa $out/wskpn-6e-ft; next: ZERO=0 BASE=0 TAG=runs MODELS=\"/tmp/albedo-history/wskpn-6e-ft.onnx /tmp/albedo-history/wskpn-6e-aa.onnx\" bash $out/eval.sh"
