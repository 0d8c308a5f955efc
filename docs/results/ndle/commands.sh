#!/usr/bin/env bash
# The ndle-s model card's training and evaluations (issue 16, NDLE on the per-sample path):
# data/curves-test and data/long-slow, sequences at 1 and 4 spp and stills at 1/2/4/8, beside
# anf-s and the shipped wskpn-6 and Open Image Denoise high.
# Data: data/render-curves*.sh in models/anf-s.md; data/long-slow: docs/render-queue.sh.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/ndle
# mcdenoise train ndle-s --data data/curves-train --out runs/ndle-s --spp 1 2 4 8 --steps 4000 \
#   --lr-schedule cosine --minutes 75 --val-every 500 --test data/curves-test --threads 1
# mcdenoise export runs/ndle-s --out models/ndle-s.onnx          (run folder: docs/results/ndle/run)
models="models/ndle-s.onnx models/anf-s.onnx models/wskpn-6.onnx"
for spp in 1 4; do
  mcdenoise evaluate $models --data data/curves-test --spp $spp --warmup 2 --threads 1 --json $out/ndle-curves-test-${spp}spp.json
  mcdenoise evaluate $models --data data/long-slow --spp $spp --warmup 8 --threads 1 --json $out/ndle-long-slow-${spp}spp.json
done
for data in curves-test long-slow; do
  for spp in 1 2 4 8; do
    mcdenoise evaluate $models --data data/$data --spp $spp --stills --threads 1 --json $out/ndle-stills-$data-${spp}spp.json
  done
done
python -m mcdenoise.export.timing --what models --specs ndle-s --sizes 1280x720 --spp 8 --repeats 2 --warmup 1 --threads 1
python -m mcdenoise.training.memory models/ndle-s.onnx 1280x720 --spp 8 --frames 2 --threads 1
