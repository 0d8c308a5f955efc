#!/usr/bin/env bash
# Render and train at scale on a lent GPU machine, one command (issue 15). Not yet run: no GPU
# was lent to the session that wrote it. The machine has torch (CUDA), onnx and numpy but no
# network, Mitsuba or OpenEXR; so first, here:
#   python -m mcdenoise.training.carry --out .gpu/wheels --variants cuda_ad_rgb   # ~55 MB (Mitsuba stripped)
# then, with the device tool (carry [".gpu"]; the tracked tree is ~8 MB more):
#   bash docs/results/device/gpu_train.sh SPEC[,SPEC...] SCENES MINUTES
# (several specs train one after another on the same rendered shard, MINUTES each; SEED=N picks
# the shard's seed, default 10, a new one each session of a chain; FIREFLIES=D trains with the
# outlier augmentation; EMA=DECAY keeps the weights' moving average (train --ema); AUTOCAST=bf16
# runs the convolutions in bfloat16 (train --autocast; not yet A/B-tested for quality); COARSE=W adds
# the loss of 8x8 block means (train --coarse-weight; docs/results/coarse); with one
# spec, INIT=RUN_FOLDER starts it from that run's weights, e.g. the last committed sitting of
# docs/results/scale, so a GPU session continues the CPU sittings' chain; LOADER_WORKERS=N
# processes build the batches, default 12 of the 16 cores: one core needs 0.88 s for a batch
# of 16 8-frame 128x128 items, many times a GPU step, so without them the GPU mostly waits)
# It renders SCENES procedural scenes (8 frames, 256x256, 8 spp, 256-spp references, half of
# them enclosed rooms) with Mitsuba's CUDA variant, trains SPEC on the GPU for MINUTES with
# spp drawn from 1..8, 8-frame windows and the temporal term, and leaves the run folder in
# $OUT for `mcdenoise export` here (export needs onnxruntime, which the machine lacks).
# A dry run on a CPU machine, before spending GPU minutes (what the last session checked):
#   OUT=/tmp/gpu-dry DEVICE=cpu VARIANT=auto SIZE=64x64 REF_SPP=16 bash docs/results/device/gpu_train.sh wskpn-3,ndle-s 6 0.3
# (2026-12-02, 2 vCPUs: render 79 s, trains 46 and 74 s, both run folders exported here; with one
# scene the trainer stops at once: its validation split, by scene seed, is empty. Again 2026-12-07
# with the next session's planned command, on today's code: OUT=/tmp/gpu-dry DEVICE=cpu VARIANT=auto
# SIZE=64x64 REF_SPP=16 SEED=41 FIREFLIES=0.001 INIT=docs/results/scale/wskpn-6e-6 LOADER_WORKERS=1
# bash docs/results/device/gpu_train.sh wskpn-6e-aa 6 0.3: render 79 s, train 484 s beside two other
# trainings, exported here)
set -euo pipefail
spec=${1:-wskpn-6}; scenes=${2:-32}; minutes=${3:-4}
device=${DEVICE:-cuda}; variant=${VARIANT:-cuda_ad_rgb}; size=${SIZE:-256x256}; ref_spp=${REF_SPP:-256}
site=/tmp/mcdenoise-site
mkdir -p "$site/mcdenoise" "$OUT"
if [ -d .gpu/wheels ]; then python -m pip install -q --no-index --no-deps --target "$site" .gpu/wheels/*.whl; fi
# The package without building it: its namespace as links to the checkout's folders
# (runtime.data_path resolves the links, so the shipped data is found in the checkout).
cp mcdenoise/__init__.py "$site/mcdenoise/"
for d in runtime training export; do ln -sfn "$PWD/$d" "$site/mcdenoise/$d"; done
export PYTHONPATH="$site"
mcd() { python -m mcdenoise.runtime.cli "$@"; }
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee "$OUT/gpu.txt" || true
start=$(date +%s)
seed=${SEED:-10}   # a chain never sees one shard seed twice: give each GPU session its own (CPU sittings use 20-27)
mcd render --out "/tmp/data/shard-$seed" --scenes "$scenes" --frames 8 --size "$size" --spp 8 --ref-spp "$ref_spp" \
  --seed "$seed" --enclosed 0.5 --variant "$variant" --workers 2 2> "$OUT/render.log"
echo "render: $(( $(date +%s) - start )) s for $scenes scenes (seed $seed)" | tee "$OUT/times.txt"
cp "/tmp/data/shard-$seed/manifest.json" "$OUT/manifest.json"
for one in ${spec//,/ }; do
  # per-frame models (NDLE) train on single frames; the temporal ones on 8-frame windows
  window=8; if grep -q '^window = 1' "models_spec/$one.toml"; then window=1; fi
  start=$(date +%s)
  mcd train "$one" --data /tmp/data --out "$OUT/run-$one" --device "$device" --minutes "$minutes" --steps 1000000 \
    --spp 1 2 4 8 --window "$window" --temporal-weight 0.25 --batch-size 16 --crop 128 --val-every 200 --quiet \
    --loader-workers "${LOADER_WORKERS:-12}" \
    ${INIT:+--init "$INIT"} --fireflies "${FIREFLIES:-0}" ${EMA:+--ema "$EMA"} ${AUTOCAST:+--autocast "$AUTOCAST"} ${COARSE:+--coarse-weight "$COARSE"} \
    2> "$OUT/train-$one.log" || echo "train $one failed" | tee -a "$OUT/times.txt"
  echo "train $one: $(( $(date +%s) - start )) s" | tee -a "$OUT/times.txt"
  tail -n 3 "$OUT/train-$one.log"
done
