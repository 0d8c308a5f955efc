#!/usr/bin/env bash
# One arm of the emitter study: spec SPEC (a file in docs/results/emitters/specs, without .toml) from scratch
# on DATA (default data/cheap-more, the 56 scenes scratch-more trained on) with scratch-more.sh's recipe
# (3000 cosine steps at 1e-3, seed 0, spp 1 2 4 8, curves-test scored every 500 steps) into run folder RUN
# (default SPEC), then scratch-more-2.sh's second cycle (4000 cosine steps at 5e-4, seed 1) into RUN-2 when
# CYCLES=2. THREADS: trainer threads (default 1). Resumes at every step.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/emitters
spec=$out/specs/$SPEC.toml
run=$out/${RUN:-$SPEC}
data=${DATA:-data/cheap-more}
train() {  # run folder, then the trainer's flags
  local r=$1; shift
  mcdenoise train $spec --data $data --out $r $([ -f $r/checkpoint.pt ] && echo --resume) "$@" --minutes 10000 \
    --lr-schedule cosine --spp 1 2 4 8 --test data/curves-test --threads "${THREADS:-1}" --quiet
}
train $run --steps "${STEPS:-3000}" --val-every 500 --seed 0
if [ "${CYCLES:-1}" = 2 ]; then
  if [ -f $run-2/checkpoint.pt ]; then train $run-2 --steps 4000 --lr 5e-4 --val-every 1000 --seed 1
  else train $run-2 --init $run --steps 4000 --lr 5e-4 --val-every 1000 --seed 1; fi
fi
