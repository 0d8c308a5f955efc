#!/usr/bin/env bash
# The 4-block 3x3 wskpn-3-aa (cos-conv-3-blocks-4: 3000 cosine steps) trained on, to compare with the
# shipped wskpn-3-aa at a budget closer to its 7439 steps: a second cosine cycle (a warm restart at half
# the spec's rate) of STEPS more steps from that run's weights, the same data and flags, one thread;
# then exported to /tmp/cheap-wskpn/long-conv-3-blocks-4.onnx. A run cut short resumes.
# NAME=conv-5 does the same for the 5x5 network (cos-conv-5 -> long-conv-5): what the data buys
# the shipped architecture, against what wskpn-4x3-aa's network adds.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/cheap-wskpn
name=${NAME:-conv-3-blocks-4}
run=$out/long-$name
if [ -f $run/checkpoint.pt ]; then from="--resume"; else from="--init $out/cos-$name"; fi
mcdenoise train $out/specs/wskpn-3-aa-$name.toml --data data/curves-train --out $run $from \
  --steps "${STEPS:-7000}" --minutes 10000 --lr 5e-4 --lr-schedule cosine --spp 1 2 4 8 --max-sequences 19 \
  --test data/curves-test --val-every 1000 --threads "${THREADS:-1}" --seed 1 --quiet
mkdir -p /tmp/cheap-wskpn
mcdenoise export $run --out /tmp/cheap-wskpn/long-$name.onnx
