#!/usr/bin/env bash
# Issue 15 (wskpn-3 under a third of Open Image Denoise fast's time at 1280x720) and issue 17 (the
# AMX host's 0.38x of Open Image Denoise high): does a cheaper prediction network keep the picture?
# wskpn-3-aa from scratch with its RepVGG blocks fused to 5x5 (shipped: 5x5, 3x3 and 1x1 branches)
# against 3x3 (3x3 and 1x1 branches: 9/25 of the multiply-adds, a 7x7 receptive field instead of
# 13x13), same data, seed, steps and flags, one process per variant on a 2-vCPU CPU.
# Data: data/curves-train and data/curves-test, rendered by docs/results/curves/commands.sh (its
# two render commands, about 25 and 10 minutes with --workers 2); 19 training sequences (of the 24,
# the seed-hash split holds 5 out), as the wskpn-6 curves of docs/results/curves.
# Re-running resumes every run folder (raise STEPS to extend).
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/cheap-wskpn
run() { mcdenoise curves wskpn-3-aa --data data/curves-train --test data/curves-test --out $out \
  --sequences 19 --steps "${STEPS:-3000}" --eval-every 500 --spp 1 2 4 8 --threads 1 --vary conv "$@"; }
run 5 > /tmp/cheap-wskpn-5.log 2>&1 &
run 3 > /tmp/cheap-wskpn-3.log 2>&1 &
wait
# then a fourth 3x3 block (a 9x9 receptive field) on the spec the first call wrote, its chart apart
mcdenoise curves $out/specs/wskpn-3-aa-conv-3.toml --data data/curves-train --test data/curves-test --out $out \
  --sequences 19 --steps "${STEPS:-3000}" --eval-every 500 --spp 1 2 4 8 --threads 1 --vary blocks 4
for f in md json png; do mv $out/curves.$f $out/curves-blocks4.$f; done
run 5 3
# each run's last checkpoint as ONNX, scored through the runtime driver on the held-out sequences
# (temporal state on, 4 warm-up frames) at 1 and 4 spp, one at a time
for v in 5 3; do
  mcdenoise export $out/wskpn-3-aa-conv-$v-n19 --out /tmp/cheap-wskpn/conv-$v.onnx
done
for spp in 1 4; do
  mcdenoise evaluate /tmp/cheap-wskpn/conv-5.onnx /tmp/cheap-wskpn/conv-3.onnx models/wskpn-3-aa.onnx oidn-fast --no-oidn \
    --data data/curves-test --spp $spp --warmup 4 --threads 1 > $out/evaluate-${spp}spp.txt
done
