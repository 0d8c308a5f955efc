#!/usr/bin/env bash
# One more point of the data curve (19 -> 56 -> 88 scenes), tilted toward open scenes: 32 more procedural scenes
# (seed 13, 128x128, 8 frames, 8 stored spp, 256-spp references, a quarter enclosed rooms where curves-train and
# shard-12 have half: long-slow, the bar's set, is two open scenes) in data/cheap-open beside symlinks to
# curves-train and cheap-more/shard-12 (so cheap-more stays what scratch-more trained on). Then the 4x3 spec
# from scratch with scratch-more.sh's recipe (3000 cosine steps at 1e-3, seed 0) and scratch-more-2.sh's second
# cycle (4000 cosine steps at 5e-4, seed 1): run folders open-1 and open-2. Scored through the driver beside
# wskpn-4x3-aa and Open Image Denoise fast on every rendered set of SETS at 1, 4 and 8 spp:
# open-2-<set>-<spp>spp.txt (compare scratch-more-2-<set>-<spp>spp.txt; the shared rows are the same run's).
# THREADS: trainer and driver threads (default 1). Resumes at every step.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/cheap-wskpn
mkdir -p data/cheap-open
ln -sfn ../curves-train data/cheap-open/curves-train
ln -sfn ../cheap-more/shard-12 data/cheap-open/shard-12
mcdenoise render --out data/cheap-open/shard-13 --scenes 32 --frames 8 --spp 8 --ref-spp 256 --size 128x128 \
  --seed 13 --enclosed 0.25 --workers 2 < /dev/null
train() {  # run, then the trainer's flags
  local run=$out/$1; shift
  mcdenoise train $out/specs/wskpn-3-aa-conv-3-blocks-4.toml --data data/cheap-open --out $run \
    $([ -f $run/checkpoint.pt ] && echo --resume) "$@" --minutes 10000 --lr-schedule cosine --spp 1 2 4 8 \
    --test data/curves-test --threads "${THREADS:-1}" --quiet
}
train open-1 --steps 3000 --val-every 500 --seed 0
if [ -f $out/open-2/checkpoint.pt ]; then train open-2 --steps 4000 --lr 5e-4 --val-every 1000 --seed 1
else train open-2 --init $out/open-1 --steps 4000 --lr 5e-4 --val-every 1000 --seed 1; fi
mkdir -p /tmp/cheap-wskpn
mcdenoise export $out/open-2 --out /tmp/cheap-wskpn/open-2.onnx
for set in ${SETS:-curves-test long-slow heldout-room_window}; do
  [ -f data/$set/manifest.json ] || { echo "data/$set not rendered, skipped" >&2; continue; }
  warm=8; [ $set = curves-test ] && warm=4
  for spp in 1 4 8; do
    mcdenoise evaluate /tmp/cheap-wskpn/open-2.onnx models/wskpn-4x3-aa.onnx oidn-fast --no-oidn \
      --data data/$set --spp $spp --warmup $warm --threads "${THREADS:-1}" > $out/open-2-$set-${spp}spp.txt
  done
done
