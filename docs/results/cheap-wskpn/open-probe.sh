#!/usr/bin/env bash
# Why did the 88-scene runs (scratch-open.sh: open-1, open-2) lose 1-2 dB where 56 scenes gained? The 4x3 spec
# from scratch for STEPS (default 1000) cosine steps, seed 0, on one shard alone: shard-12 (seed 12, half
# enclosed, in the 56 that gained) against shard-13 (seed 13, a quarter enclosed, the 32 scenes added), each
# 32 scenes of 128x128; the trainer's curves-test PSNR at every 500 steps in probe-<shard>/metrics.jsonl.
# THREADS: trainer threads (default 1).
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/cheap-wskpn
for shard in cheap-more/shard-12 cheap-open/shard-13; do
  run=$out/probe-${shard#*/}
  mcdenoise train $out/specs/wskpn-3-aa-conv-3-blocks-4.toml --data data/$shard --out $run \
    $([ -f $run/checkpoint.pt ] && echo --resume) --steps "${STEPS:-1000}" --minutes 10000 --lr-schedule cosine \
    --spp 1 2 4 8 --test data/curves-test --val-every 500 --threads "${THREADS:-1}" --seed 0 --quiet
done
