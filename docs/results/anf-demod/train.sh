#!/usr/bin/env bash
# Issue 16: does ANF keep texture when its kernels filter albedo-demodulated irradiance?
# An A/B from the shipped anf-s weights (docs/results/anf/run, 319 steps), on the same data, for
# the same minutes each, one after the other on every core (two at once, one thread each, ran out
# of this VM's 24 GB: an ANF training process holds about 14 GB here):
#   anf-s-ft  anf-s trained on (the control: what more steps alone buy);
#   anf-sd    anf-sd (models_spec/anf-sd.toml: the same network, the kernels on colour / albedo)
#             started from the same weights (--init takes a run of another spec of its type).
# Usage: bash docs/results/anf-demod/train.sh MINUTES   (each arm's budget)
# Data: data/curves-train (all 24 scenes; anf-s saw 9 of them), data/curves-test for the
# validation curve; both rendered here if missing (the anf-s card's commands: about 12 minutes
# with --workers 2 on this 2-core VM, 8 for curves-test on one).
# Writes docs/results/anf-demod/<run> (small: commit them) and <run>.log; score with score.sh.
set -euo pipefail
cd "$(dirname "$0")/../../.."
minutes=$1
out=docs/results/anf-demod
bash docs/results/curves/data.sh
for pair in "anf-sd anf-sd" "anf-s anf-s-ft"; do
  read -r spec run <<< "$pair"
  # The spec's [train] otherwise (Eq. 9's loss, lr 5e-4 constant, batch 4 of 8-frame windows,
  # 64x64 crops, S from 1, 2, 4, 8); the seed differs from the first run's 0 so that the
  # continued runs draw new crops.
  mcdenoise train "$spec" --data data/curves-train --out "$out/$run" --init docs/results/anf/run \
    --minutes "$minutes" --val-every "${VAL_EVERY:-50}" --test data/curves-test --threads "$(nproc)" --seed 1 \
    --quiet > "$out/$run.log" 2>&1
done
echo "trained: $out/anf-s-ft $out/anf-sd; next: bash $out/score.sh"
