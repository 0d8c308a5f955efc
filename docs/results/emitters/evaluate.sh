#!/usr/bin/env bash
# Score the emitter study's runs through the runtime driver (temporal state on, PSNR after warm-up), one
# evaluate call per set and spp so every row of a table is one run on one render: RUNS (run folders under
# docs/results/emitters, default every arm's final run) beside scratch-more-2 (docs/results/cheap-wskpn: the
# shipped wskpn-4x3-aa's weights, no emissive layer) or the baseline BASE, and Open Image Denoise fast.
# SETS (default curves-test long-slow heldout-room_window), SPPS (default 1 4 8); writes
# <set>-<spp>spp.txt here (TAG-<set>-<spp>spp.txt with TAG set). THREADS: driver threads (default 1).
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/emitters
mkdir -p /tmp/emitters
models=()
for r in ${BASE:-docs/results/cheap-wskpn/scratch-more-2} ${RUNS:-}; do
  [ -d $r ] || r=$out/$r
  name=$(basename $r)
  if [ ! /tmp/emitters/$name.onnx -nt $r/checkpoint.pt ]; then
    # exported under the run folder's name (evaluate names a method by its spec: two cycles or two data sets of
    # one spec would collide)
    rm -rf /tmp/emitters/runs/$name && mkdir -p /tmp/emitters/runs && cp -r $r /tmp/emitters/runs/$name
    [ $r = ${BASE:-docs/results/cheap-wskpn/scratch-more-2} ] || \
      sed -i "s/^name = .*/name = \"$name\"/" /tmp/emitters/runs/$name/spec.toml
    mcdenoise export /tmp/emitters/runs/$name --out /tmp/emitters/$name.onnx > /dev/null
  fi
  models+=(/tmp/emitters/$name.onnx)
done
for set in ${SETS:-curves-test long-slow heldout-room_window}; do
  [ -f data/$set/manifest.json ] || { echo "data/$set not rendered, skipped" >&2; continue; }
  warm=8; [ $set = curves-test ] && warm=4
  for spp in ${SPPS:-1 4 8}; do
    mcdenoise evaluate "${models[@]}" oidn-fast --no-oidn --data data/$set --spp $spp --warmup $warm \
      --threads "${THREADS:-1}" > $out/${TAG:+$TAG-}$set-${spp}spp.txt
  done
done
