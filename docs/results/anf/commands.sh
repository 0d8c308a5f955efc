#!/usr/bin/env bash
# The anf-s model card's evaluations (issue 16): data/curves-test and data/long-slow at 1 and 4
# spp beside the shipped wskpn models, svgf and Open Image Denoise, and the kernel-size sweep.
# data/long-slow: python -c "from mcdenoise.training.testsets import LONG_SEQUENCES as L; print(' '.join(L['slow'].render_args()))"
set -e
cd "$(dirname "$0")/../../.."
for spp in 1 4; do
  mcdenoise evaluate models/anf-s.onnx models/wskpn-6.onnx models/wskpn-3.onnx svgf --data data/curves-test --spp $spp --warmup 2 --json docs/results/anf/curves-test-${spp}spp.json
done
for spp in 1 4; do
  mcdenoise evaluate models/anf-s.onnx models/wskpn-6.onnx --data data/long-slow --spp $spp --warmup 8 --json docs/results/anf/long-slow-${spp}spp.json
done
mcdenoise sweep models/anf-s.onnx --data data/curves-test --values 3 5 7 9 11 13 15 17 19 --spp 4 --out docs/results/anf/sweep
