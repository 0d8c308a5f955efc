#!/usr/bin/env bash
# Scores longer.sh's model (/tmp/cheap-wskpn/long-conv-3-blocks-4.onnx), the shipped wskpn-3-aa and Open Image Denoise fast through the
# runtime driver, temporal state on: on data/curves-test after 4 warm-up frames, and on the hand-made
# held-out room (data/heldout-room_window, never trained on; rendered by the command
# `python -c "from mcdenoise.training.testsets import HELD_OUT; print(HELD_OUT['room_window'].command())"`
# prints) after 8, at 1, 4 and 8 spp. Writes docs/results/cheap-wskpn/longer-<set>-<spp>spp.txt.
# NAME=conv-5 scores longer.sh's 5x5 network (/tmp/cheap-wskpn/long-conv-5.onnx) beside the shipped
# wskpn-4x3-aa and wskpn-3-aa instead, into longer-conv-5-<set>-<spp>spp.txt.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/cheap-wskpn
name=${NAME:-conv-3-blocks-4}
models="/tmp/cheap-wskpn/long-$name.onnx models/wskpn-3-aa.onnx oidn-fast"; tag=longer
[ $name = conv-3-blocks-4 ] || { models="/tmp/cheap-wskpn/long-$name.onnx models/wskpn-4x3-aa.onnx models/wskpn-3-aa.onnx oidn-fast"; tag=longer-$name; }
mkdir -p /tmp/cheap-wskpn
[ -f /tmp/cheap-wskpn/long-$name.onnx ] || mcdenoise export $out/long-$name --out /tmp/cheap-wskpn/long-$name.onnx
for set in ${SETS:-curves-test heldout-room_window}; do
  [ -f data/$set/manifest.json ] || { echo "data/$set not rendered, skipped" >&2; continue; }
  warm=8; [ $set = curves-test ] && warm=4
  for spp in 1 4 8; do
    mcdenoise evaluate $models --no-oidn --data data/$set --spp $spp --warmup $warm --threads "${THREADS:-1}" \
      > $out/$tag-$set-${spp}spp.txt
  done
done
