#!/usr/bin/env bash
# The shipped models and Open Image Denoise on the frames the sittings are scored on
# (data/curves-test: sitting.sh renders it), for docs/results/scale/table.py.
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=docs/results/scale/baseline
mkdir -p "$out"
for spp in 1 4; do
  mcdenoise evaluate models/wskpn-6.onnx models/wskpn-3.onnx --data data/curves-test --spp $spp --warmup 2 \
    --json "$out/curves-test-${spp}spp.json"
done
for spp in 1 2 4 8; do
  mcdenoise evaluate models/wskpn-6.onnx models/wskpn-3.onnx --data data/curves-test --spp $spp --stills \
    --json "$out/stills-curves-test-${spp}spp.json"
done
