#!/usr/bin/env bash
# Ran 2026-12-07 (README, "More scenes, as a third cycle": lost 0.06-0.56 dB; scratch-more.sh then trained from
# scratch on the same data and gained): more scenes of the kind that gained wskpn-4x3-aa the room.
# Renders 32 more curves-train-like scenes (another seed; 128x128, 8 frames, 8 stored spp, 256-spp references,
# half enclosed rooms; resumes per frame, about 15 minutes on two idle cores) beside data/curves-train
# (a symlink, so the trainer's discover() sees both as shards of data/cheap-more), then trains the shipped
# run (long-conv-3-blocks-4) a third cosine cycle on all of it (STEPS, default 4000, at 3e-4, one thread
# per THREADS) into long-more, exports /tmp/cheap-wskpn/long-more.onnx and scores it through the driver
# beside the shipped file on curves-test, the hand-made room and long-slow (its own evaluate call, as evaluate-longer.sh).
# Note the validation split is drawn over all 56 seeds, so the run's val PSNR is not comparable with
# earlier runs'; curves-test (--test) is.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/cheap-wskpn
mkdir -p data/cheap-more && ln -sfn ../curves-train data/cheap-more/curves-train
mcdenoise render --out data/cheap-more/shard-12 --scenes 32 --frames 8 --spp 8 --ref-spp 256 --size 128x128 \
  --seed 12 --enclosed 0.5 --workers 2 < /dev/null
run=$out/long-more
if [ -f $run/checkpoint.pt ]; then from="--resume"; else from="--init $out/long-conv-3-blocks-4"; fi
mcdenoise train $out/specs/wskpn-3-aa-conv-3-blocks-4.toml --data data/cheap-more --out $run $from \
  --steps "${STEPS:-4000}" --minutes 10000 --lr 3e-4 --lr-schedule cosine --spp 1 2 4 8 \
  --test data/curves-test --val-every 1000 --threads "${THREADS:-1}" --seed 2 --quiet
mkdir -p /tmp/cheap-wskpn
mcdenoise export $run --out /tmp/cheap-wskpn/long-more.onnx
for set in curves-test heldout-room_window long-slow; do
  warm=8; [ $set = curves-test ] && warm=4
  for spp in 1 4 8; do
    mcdenoise evaluate /tmp/cheap-wskpn/long-more.onnx models/wskpn-4x3-aa.onnx oidn-fast --no-oidn --data data/$set \
      --spp $spp --warmup $warm --threads "${THREADS:-1}" > $out/more-$set-${spp}spp.txt
  done
done
