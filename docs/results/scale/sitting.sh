#!/usr/bin/env bash
# One sitting of issue 15's training at scale on a CPU machine that does not keep its files.
#
# Each sitting renders its own 256x256 shards, trains a *new* run that starts from the previous
# sitting's weights and Adam state (`mcdenoise train --init`), and scores it on the held-out
# curves-test set. Run folders are small, so they are committed. The shards are not: a fresh
# machine renders other seeds, and the chain sees more scenes with every sitting.
#
# Usage: SHARDS="20 27" bash docs/results/scale/sitting.sh K RENDER_MIN TRAIN_MIN [SPEC]
#   (LR=RATE: train --lr RATE, the peak of this sitting's cosine (default: the spec's 1e-3; a
#   sitting starts its schedule at the top again, so give STEPS it can finish: sitting 4 ended a
#   third of the way down at 1e-3 and 0.5-0.85 dB below the sitting before);
#   FIREFLIES=D: train --fireflies D, the outlier augmentation; default 0; EMA=DECAY: train --ema
#   DECAY, the weights' moving average that validation scores and export ships; default off;
#   COARSE=W: train --coarse-weight W, the loss of 8x8 block means (docs/results/coarse); default off;
#   CLIP=NORM: train --clip-grad NORM, the largest gradient norm a step takes (mr-e sitting 4 lost 2.5 dB
#   between two validations without it); default off;
#   CACHE=DIR: train --cache-dir DIR, the decoded frames kept on disk for the next run on this machine)
#   K           this sitting's number: its run is docs/results/scale/<SPEC>-<K>, started from
#               <SPEC>-<K-1>; sitting 1 starts from scratch, or from INIT=RUN_FOLDER.
#   RENDER_MIN  minutes of rendering, one shard per core at once, the SHARDS in order as a queue
#               (a core whose shard completes starts the next one; 0: train on what is there).
#               The renders resume per frame, so the next call on this machine goes on with them.
#   TRAIN_MIN   the training budget in minutes, on every core (its cosine rate is planned
#               over STEPS, default 2400, and stops at whichever comes first). Train with
#               nothing else running: a render at nice 19 beside it made a wskpn-6 step 10-60x
#               slower here (0.6 s alone on 2 threads; 6-40 s beside two renders); autogroup
#               scheduling, which ignores nice across sessions, may explain much of it (not
#               measured; docs/nice19.sh, used below, lowers the render's session too).
# Shards: data/train-256/shard-<seed>, 32 scenes x 8 frames, 8 stored spp, 256-spp references,
# half enclosed rooms (docs/render-queue.sh). Never give two sittings of one chain the same seed.
set -euo pipefail
cd "$(dirname "$0")/../../.."
k=$1; render_min=$2; train_min=$3; spec=${4:-wskpn-6}
out=docs/results/scale
run=${RUN:-$out/$spec-$k}    # RUN: another folder, e.g. for a second variant of one spec
if [ "$k" = 1 ]; then init=${INIT:-}; else init=${INIT:-$out/$spec-$((k - 1))}; fi
[ -n "${SHARDS:-}" ] || { echo "sitting.sh: give the shard seeds of this sitting in SHARDS, e.g. SHARDS=\"20 27\"" >&2; exit 2; }
cores=$(nproc)

mkdir -p data
# The held-out set every sitting is scored on (minutes; skipped where it is complete).
mcdenoise render --out data/curves-test --scenes 4 --frames 8 --spp 8 --ref-spp 512 --size 128x128 \
  --seed 11 --enclosed 0.5 --workers 1 < /dev/null

if [ "$render_min" != 0 ]; then
  # SHARDS is a queue shared out round-robin, one worker per core, so a core whose shard finishes
  # early goes on with its next one instead of idling until the deadline.
  deadline=$(( $(date +%s) + render_min * 60 ))
  read -r -a queue <<< "$SHARDS"
  pids=()
  for ((w = 0; w < cores && w < ${#queue[@]}; w++)); do
    (
      for ((i = w; i < ${#queue[@]}; i += cores)); do
        seed=${queue[$i]}; left=$(( deadline - $(date +%s) ))
        [ "$left" -gt 0 ] || break
        timeout "$left" docs/nice19.sh mcdenoise render --out "data/train-256/shard-$seed" \
          --scenes 32 --frames 8 --size 256x256 --spp 8 --ref-spp 256 --seed "$seed" --enclosed 0.5 \
          --workers 1 < /dev/null >> "data/render-shard-$seed.log" 2>&1 || true    # a timeout ends a render on purpose
      done
    ) &
    pids+=($!)
  done
  for p in "${pids[@]}"; do wait "$p" || true; done
fi

# Sequences still rendering hold .partial.json and are left out by the data set.
mcdenoise train "$spec" --data data/train-256 --out "$run" ${init:+--init "$init"} --spp 1 2 4 8 --window 8 \
  --temporal-weight 0.25 --steps "${STEPS:-2400}" ${LR:+--lr "$LR"} --lr-schedule cosine --minutes "$train_min" \
  --val-every "${VAL_EVERY:-300}" --test data/curves-test --threads "$cores" --fireflies "${FIREFLIES:-0}" ${EMA:+--ema "$EMA"} ${COARSE:+--coarse-weight "$COARSE"} ${CLIP:+--clip-grad "$CLIP"} ${CACHE:+--cache-dir "$CACHE"} --quiet
python - "$run" "$SHARDS" <<'EOF'
import json, sys
from mcdenoise.training.dataset import discover
run, shards = sys.argv[1], sys.argv[2].split()
seqs = discover("data/train-256")
# Every sequence the run read (the trainer's split holds out a fifth of the seeds for validation).
json.dump({"shards": shards, "sequences": len(seqs), "frames": sum(len(s.frames) for s in seqs),
           "scene_seeds": [s.seed for s in seqs]}, open(f"{run}/data.json", "w"), indent=1)
EOF

m=/tmp/$(basename "$run").onnx
mcdenoise export "$run" --out "$m"
for spp in 1 4; do
  mcdenoise evaluate "$m" --no-oidn --data data/curves-test --spp $spp --warmup 2 --json "$run/curves-test-${spp}spp.json"
done
for spp in 1 2 4 8; do
  mcdenoise evaluate "$m" --no-oidn --data data/curves-test --spp $spp --stills --json "$run/stills-curves-test-${spp}spp.json"
done
