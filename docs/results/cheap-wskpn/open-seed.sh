#!/usr/bin/env bash
# Is open-1's loss (88 scenes, scratch-open.sh's first cycle) the data or the run? The same recipe (3000 cosine
# steps from scratch at 1e-3, spp 1-8, data/cheap-open) with another training seed SEED (default 1): run folder
# open-1-s<SEED>, the trainer's curves-test PSNR and relMSE every 500 steps in its metrics.jsonl (against open-1:
# 25.80 -> 25.33 dB, relMSE 1.6-7.1; scratch-more, 56 scenes: 25.82 -> 26.56, 0.26-0.74).
# THREADS: trainer threads (default 1). Resumes.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/cheap-wskpn
seed=${SEED:-1}
run=$out/open-1-s$seed
mcdenoise train $out/specs/wskpn-3-aa-conv-3-blocks-4.toml --data data/cheap-open --out $run \
  $([ -f $run/checkpoint.pt ] && echo --resume) --steps 3000 --minutes 10000 \
  --lr-schedule cosine --spp 1 2 4 8 --test data/curves-test --val-every 500 --threads "${THREADS:-1}" \
  --seed "$seed" --quiet
