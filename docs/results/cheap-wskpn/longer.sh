#!/usr/bin/env bash
# The 4-block 3x3 wskpn-3-aa (cos-conv-3-blocks-4: 3000 cosine steps) trained on, to compare with the
# shipped wskpn-3-aa at a budget closer to its 7439 steps: a second cosine cycle (a warm restart at half
# the spec's rate) of STEPS more steps from that run's weights, the same data and flags, one thread;
# then exported to /tmp/cheap-wskpn/long-conv-3-blocks-4.onnx. A run cut short resumes.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/cheap-wskpn
run=$out/long-conv-3-blocks-4
if [ -f $run/checkpoint.pt ]; then from="--resume"; else from="--init $out/cos-conv-3-blocks-4"; fi
mcdenoise train $out/specs/wskpn-3-aa-conv-3-blocks-4.toml --data data/curves-train --out $run $from \
  --steps "${STEPS:-7000}" --minutes 10000 --lr 5e-4 --lr-schedule cosine --spp 1 2 4 8 --max-sequences 19 \
  --test data/curves-test --val-every 1000 --threads 1 --seed 1 --quiet
mkdir -p /tmp/cheap-wskpn
mcdenoise export $run --out /tmp/cheap-wskpn/long-conv-3-blocks-4.onnx
