#!/usr/bin/env bash
# scratch-more's second cosine cycle, as longer.sh gave cos-conv-3-blocks-4 the one that made wskpn-4x3-aa:
# from scratch-more's weights, a warm restart at 5e-4 decayed by a cosine over STEPS (default 4000; the
# shipped run took 7000, its curves-test score flat over the last 4000), seed 1, on data/cheap-more
# (curves-train + shard-12, 56 scenes; more.sh renders it). Then scored through the driver beside the shipped
# wskpn-4x3-aa and Open Image Denoise fast on every set of SETS that is rendered (default curves-test and
# long-slow; heldout-room_window when present), at 1, 4 and 8 spp: scratch-more-2-<set>-<spp>spp.txt.
# THREADS: trainer and driver threads (default 1). A run cut short resumes.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/cheap-wskpn
run=$out/scratch-more-2
if [ -f $run/checkpoint.pt ]; then from="--resume"; else from="--init $out/scratch-more"; fi
mcdenoise train $out/specs/wskpn-3-aa-conv-3-blocks-4.toml --data data/cheap-more --out $run $from \
  --steps "${STEPS:-4000}" --minutes 10000 --lr 5e-4 --lr-schedule cosine --spp 1 2 4 8 \
  --test data/curves-test --val-every 1000 --threads "${THREADS:-1}" --seed 1 --quiet
mkdir -p /tmp/cheap-wskpn
mcdenoise export $run --out /tmp/cheap-wskpn/scratch-more-2.onnx
for set in ${SETS:-curves-test long-slow heldout-room_window}; do
  [ -f data/$set/manifest.json ] || { echo "data/$set not rendered, skipped" >&2; continue; }
  warm=8; [ $set = curves-test ] && warm=4
  for spp in 1 4 8; do
    mcdenoise evaluate /tmp/cheap-wskpn/scratch-more-2.onnx models/wskpn-4x3-aa.onnx oidn-fast --no-oidn \
      --data data/$set --spp $spp --warmup $warm --threads "${THREADS:-1}" > $out/scratch-more-2-$set-${spp}spp.txt
  done
done
