#!/usr/bin/env bash
# The data-only comparison more.sh could not give: the 4x3 spec from scratch on data/cheap-more (curves-train +
# shard-12, 56 scenes; more.sh renders it) with cosine.sh's recipe (3000 cosine steps, seed 0, spp 1-8), so
# against cos-conv-3-blocks-4 (the same on curves-train's first 19 training scenes) data is the only difference.
# Then scored through the driver on long-slow (where the curves-train runs lost) and curves-test, at 1 spp,
# beside cos-conv-3-blocks-4: scratch-more-<set>-1spp-<run>.txt. THREADS: trainer and driver threads (default 1).
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/cheap-wskpn
run=$out/scratch-more
mcdenoise train $out/specs/wskpn-3-aa-conv-3-blocks-4.toml --data data/cheap-more --out $run \
  $([ -f $run/checkpoint.pt ] && echo --resume) --steps "${STEPS:-3000}" --minutes 10000 --lr-schedule cosine \
  --spp 1 2 4 8 --test data/curves-test --val-every 500 --threads "${THREADS:-1}" --seed 0 --quiet
mkdir -p /tmp/cheap-wskpn
mcdenoise export $run --out /tmp/cheap-wskpn/scratch-more.onnx
[ -f /tmp/cheap-wskpn/cos-conv-3-blocks-4.onnx ] || mcdenoise export $out/cos-conv-3-blocks-4 --out /tmp/cheap-wskpn/cos-conv-3-blocks-4.onnx
# One evaluate call per file: both carry the spec's name, and evaluate refuses two models of one name.
for set in long-slow curves-test; do
  warm=8; [ $set = curves-test ] && warm=4
  for m in scratch-more cos-conv-3-blocks-4; do
    mcdenoise evaluate /tmp/cheap-wskpn/$m.onnx --no-oidn --data data/$set --spp 1 --warmup $warm \
      --threads "${THREADS:-1}" > $out/scratch-more-$set-1spp-$m.txt
  done
done
