#!/usr/bin/env bash
# Issue 15's bar for the wskpn-3 class is scored on the long sequences (training/testsets.py LONG_SEQUENCES:
# 2 procedural scenes of seed 6, 24 frames at 256x256, 1024-spp references; never trained on), at 1 spp after
# 8 warm-up frames: within 1 dB of Open Image Denoise fast. Scores the shipped wskpn-4x3-aa, wskpn-3-aa
# (whose numbers on the earlier render are in docs/results/albedo-history, so the re-render is checked) and
# the 5x5 retrain (longer.sh NAME=conv-5) beside Open Image Denoise fast and high, through the runtime driver,
# temporal state on, at 1, 4 and 8 spp. Render a set first with the command
# `python -c "from mcdenoise.training.testsets import LONG_SEQUENCES as L; print(L['slow'].command())"` prints.
# Writes docs/results/cheap-wskpn/bar-<set>-<spp>spp.txt.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/cheap-wskpn
mkdir -p /tmp/cheap-wskpn
[ -f /tmp/cheap-wskpn/long-conv-5.onnx ] || mcdenoise export $out/long-conv-5 --out /tmp/cheap-wskpn/long-conv-5.onnx
for set in ${SETS:-long-slow}; do
  [ -f data/$set/manifest.json ] || { echo "data/$set not rendered, skipped" >&2; continue; }
  for spp in 1 4 8; do
    mcdenoise evaluate models/wskpn-4x3-aa.onnx models/wskpn-3-aa.onnx /tmp/cheap-wskpn/long-conv-5.onnx oidn-fast oidn-high \
      --no-oidn --data data/$set --spp $spp --warmup 8 --threads "${THREADS:-1}" > $out/bar-$set-${spp}spp.txt
  done
done
