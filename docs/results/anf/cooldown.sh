#!/usr/bin/env bash
# Issue 16: the firefly-augmented anf-s fine-tune (fireflies/ff0.001, 144 steps at a constant 5e-4)
# passes the stress test's fireflies but lost 0.65 dB on clean curves-test sequences against the
# shipped file; its control arm without the augmentation lost as much, so the loss is the
# fine-tune's constant, restarted rate. This continues ff0.001 (weights and Adam state, `--init`)
# with the augmentation kept and a cosine from a lower peak, so the weights settle, then scores
# it like fireflies.sh did: stress (rendered cases left out) and curves-test at 1 and 4 spp.
# A run folder already there is resumed, so the script continues across sessions.
# Usage (after a scale sitting rendered data/train-256 and data/curves-test; nothing else running):
#   [SRC=RUN] [RUN=OUT] [CROP=48] [WINDOW=4] bash docs/results/anf/cooldown.sh [STEPS] [LR] [MINUTES]
# SRC: the run it continues (default fireflies/ff0.001), RUN: its run folder (default
# fireflies/ff0.001-cool); CROP, WINDOW: the items' crop and frames (the spec's are 64 and 8).
set -euo pipefail
cd "$(dirname "$0")/../../.."
steps=${1:-200}; lr=${2:-2e-4}; minutes=${3:-30}
src=${SRC:-docs/results/anf/fireflies/ff0.001}
run=${RUN:-docs/results/anf/fireflies/ff0.001-cool}
# the stress test's clean base set (3 scenes x 4 frames, 128x128; minutes where missing)
eval "$(python -c "from mcdenoise.training.testsets import stress_set; print(stress_set('base', 'data/stress', False).command())")" < /dev/null
if [ -f "$run/config.json" ]; then
  mcdenoise train anf-s --data data/train-256 --out "$run" --resume --minutes "$minutes" --threads "$(nproc)" \
    --quiet >> "$run.log" 2>&1
else
  # by default the same items as ff0.001's (crops, windows, spp, the first 12 training sequences of what data/ holds)
  mcdenoise train anf-s --data data/train-256 --init "$src" --out "$run" --spp 1 2 4 8 --window "${WINDOW:-4}" --crop "${CROP:-48}" \
    --temporal-weight 0.25 --lr "$lr" --lr-schedule cosine --steps "$steps" --minutes "$minutes" \
    --threads "$(nproc)" --max-sequences 12 --val-every 100 --fireflies 0.001 --quiet > "$run.log" 2>&1
fi
m=/tmp/$(basename "$run").onnx
mcdenoise export "$run" --out "$m"
mcdenoise stress "$m" noisy --no-render --out "$run-stress"
for spp in 1 4; do
  mcdenoise evaluate "$m" --no-oidn --data data/curves-test --spp $spp --warmup 2 --json "$run/curves-test-${spp}spp.json"
  [ -f "$run/shipped-curves-test-${spp}spp.json" ] || mcdenoise evaluate models/anf-s.onnx --no-oidn --data data/curves-test \
    --spp $spp --warmup 2 --json "$run/shipped-curves-test-${spp}spp.json"
done
