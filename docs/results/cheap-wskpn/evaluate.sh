#!/usr/bin/env bash
# Scores the files cosine.sh exported, the shipped wskpn-3-aa and Open Image Denoise fast through the
# runtime driver on data/curves-test (temporal state on; PSNR also after 4 warm-up frames), at 1 and 4
# spp, one thread, one file at a time. Writes docs/results/cheap-wskpn/cosine-<spp>spp.txt.
set -e
cd "$(dirname "$0")/../../.."
for spp in 1 4; do
  mcdenoise evaluate /tmp/cheap-wskpn/cos-conv-5.onnx /tmp/cheap-wskpn/cos-conv-3.onnx \
    /tmp/cheap-wskpn/cos-conv-3-blocks-4.onnx models/wskpn-3-aa.onnx oidn-fast --no-oidn \
    --data data/curves-test --spp $spp --warmup 4 --threads 1 > docs/results/cheap-wskpn/cosine-${spp}spp.txt
done
