#!/usr/bin/env bash
# Renders, one after another on one CPU core at the lowest priority, every data set the quality
# issue (#15) measures with and the first training shards at its scale; re-running resumes (the
# render command keeps finished sequences, so a stopped queue loses at most the frame in flight).
# Usage: bash docs/render-queue.sh [DATA_DIR]   (default: data/, which git ignores)
set -uo pipefail
cd "$(dirname "$0")/.."
data=${1:-data}
# The long test sequences and the hand-made held-out scenes first (what every score needs).
python - <<'PY' |
from mcdenoise.training.testsets import HELD_OUT as H, LONG_SEQUENCES as L
for s in (L["medium"], L["slow"], H["room_window"], H["lamp_occluder"], L["fast"]):
    print(" ".join(s.render_args()))
PY
while read -r args; do
  nice -n 19 mcdenoise ${args//data\//$data/} --workers 1 < /dev/null || echo "render-queue: failed: $args" >&2
done
# Training shards at the issue's scale (256x256, 8 stored spp, half enclosed rooms): one folder
# per seed under $data/train-256, merged by the data set loader; 32 scenes x 8 frames each.
for seed in 20 21 22 23 24 25 26 27; do
  nice -n 19 mcdenoise render --out "$data/train-256/shard-$seed" --scenes 32 --frames 8 --size 256x256 \
    --spp 8 --ref-spp 256 --seed "$seed" --enclosed 0.5 --workers 1 < /dev/null \
    || echo "render-queue: failed: shard $seed" >&2
done
