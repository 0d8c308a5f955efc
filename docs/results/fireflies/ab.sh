#!/usr/bin/env bash
# Does the firefly augmentation (train --fireflies) fix the stress test's firefly failures, and
# what does it cost on clean frames? Two runs of one spec, same data, budget and seed, one thread
# each side by side, with and without it; each scored by `mcdenoise stress` (every perturbation
# case, the rendered ones left out) and on data/curves-test's 1-spp sequences.
# First run 2026-12-03 (README.md here: inconclusive at 300 steps). Usage (after a sitting rendered data/train-256 and data/curves-test; nothing else running):
#   bash docs/results/fireflies/ab.sh [SPEC] [MINUTES] [DENSITY]
set -euo pipefail
cd "$(dirname "$0")/../../.."
spec=${1:-nbg-2l-1g}; minutes=${2:-8}; density=${3:-0.001}
out=docs/results/fireflies
# the stress test's clean base set (3 scenes x 4 frames, 128x128; minutes)
eval "$(python -c "from mcdenoise.training.testsets import stress_set; print(stress_set('base', 'data/stress', False).command())")" < /dev/null
for d in 0 "$density"; do
  mcdenoise train "$spec" --data data/train-256 --out "$out/$spec-ff$d" --spp 1 2 4 8 --window 8 \
    --temporal-weight 0.25 --minutes "$minutes" --steps 1000000 --threads 1 --fireflies "$d" --quiet \
    > "$out/$spec-ff$d.log" 2>&1 &
done
wait
for d in 0 "$density"; do
  m=/tmp/$spec-ff$d.onnx
  mcdenoise export "$out/$spec-ff$d" --out "$m"
  # one model a run: stress names methods by spec, and both runs are one spec
  mcdenoise stress "$m" noisy --no-render --out "$out/stress-ff$d"
  mcdenoise evaluate "$m" --no-oidn --data data/curves-test --spp 1 --warmup 2 --json "$out/$spec-ff$d/curves-test-1spp.json"
done
