#!/usr/bin/env bash
# Issue 15 ("train the specs that ship without weights today"): the two high-spp models,
# wskpn-mr (WSKPN 'Ours MR') and nbg-7l-3g (NBG 'Ours 7-layer 3-grid'), trained on the 256x256
# scale shards on a CPU, then scored on data/curves-test beside the shipped models.
#
# Usage: bash docs/results/highspp/train.sh MINUTES [SPEC...]   (default: both specs)
#   Every spec trains at once, one thread each (their steps are small, so two processes on two
#   cores should get more done than one after the other on two threads; not measured here).
#   STEPS="N ...": each spec's cosine length, in the order of the specs (plan them to end inside
#   MINUTES: the README gives seconds a step; default 12000 9500, for 52 minutes on a 2-core EPYC).
#   Data: every finished shard under data/train-256 (rendered by docs/results/scale/sitting.sh or
#   docs/render-queue.sh; the 2026-12-05 runs read shards 34-37).
# Writes docs/results/highspp/<spec> (the run folder, small enough to commit), then scores it with
# score.sh (which a finished run can be given again alone).
set -euo pipefail
cd "$(dirname "$0")/../../.."
minutes=$1; shift
specs=("$@"); [ ${#specs[@]} -gt 0 ] || specs=(wskpn-mr nbg-7l-3g)
out=docs/results/highspp
[ -d data/train-256 ] || { echo "train.sh: data/train-256 is missing; render shards first (docs/results/scale/sitting.sh)" >&2; exit 2; }
[ -f data/curves-test/manifest.json ] || mcdenoise render --out data/curves-test --scenes 4 --frames 8 --spp 8 \
  --ref-spp 512 --size 128x128 --seed 11 --enclosed 0.5 --workers 1 < /dev/null
read -r -a steps <<< "${STEPS:-12000 9500}"
pids=()
for i in "${!specs[@]}"; do
  spec=${specs[$i]}
  # Every model trains on spp drawn from 1 to 8 (issue 15), so that it gets better with more
  # samples; the window of 1 is the spec's (no temporal stage, as in both papers' high-spp models).
  mcdenoise train "$spec" --data data/train-256 --out "$out/$spec" --spp 1 2 4 8 --window 1 \
    --steps "${steps[$i]}" --lr-schedule cosine --minutes "$minutes" --val-every "${VAL_EVERY:-3000}" \
    --test data/curves-test --threads 1 ${CACHE:+--cache-dir "$CACHE"} --quiet > "$out/$spec.log" 2>&1 &
  pids+=($!)
done
for p in "${pids[@]}"; do wait "$p"; done
# Scores (curves-test stills, the held-out sets rendered here at 1, 4 and 8 spp): score.sh.
bash "$out/score.sh" "${specs[@]/#/$out/}"
