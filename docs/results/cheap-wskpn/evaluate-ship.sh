#!/usr/bin/env bash
# The shipped wskpn-4x3-aa (since the fifth session: scratch-more-2's weights, see the model card) scored through
# the runtime driver beside wskpn-3-aa and Open Image Denoise fast and high, temporal state on, on every rendered
# set of SETS (default curves-test, the hand-made room and long-slow; render commands in the card), at 1, 4 and 8
# spp, after 4 warm-up frames on curves-test and 8 elsewhere: ship-<set>-<spp>spp.txt. THREADS: driver threads.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/cheap-wskpn
for set in ${SETS:-curves-test heldout-room_window long-slow long-medium long-fast}; do
  [ -f data/$set/manifest.json ] || { echo "data/$set not rendered, skipped" >&2; continue; }
  warm=8; [ $set = curves-test ] && warm=4
  for spp in 1 4 8; do
    mcdenoise evaluate models/wskpn-4x3-aa.onnx models/wskpn-3-aa.onnx oidn-fast oidn-high --no-oidn \
      --data data/$set --spp $spp --warmup $warm --threads "${THREADS:-1}" > $out/ship-$set-${spp}spp.txt
  done
done
