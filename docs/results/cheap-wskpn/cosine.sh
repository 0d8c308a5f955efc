#!/usr/bin/env bash
# The curves (commands.sh) train at a constant learning rate, and their test points swing by up to
# 0.7 dB from one validation to the next, more than the difference sought. So each variant once more
# from scratch, the same data, seed, steps and flags, with the learning rate decayed to 0 by a cosine
# (a final point that has settled), then exported and scored through the runtime driver.
# Usage: bash docs/results/cheap-wskpn/cosine.sh SPEC_NAME [...]   (SPEC_NAME: a spec written by
# commands.sh under docs/results/cheap-wskpn/specs, e.g. wskpn-3-aa-conv-5 wskpn-3-aa-conv-3); one
# process per name, in parallel; a run cut short resumes.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/cheap-wskpn
one() {
  local run=$out/cos-${1#wskpn-3-aa-}
  mcdenoise train $out/specs/$1.toml --data data/curves-train --out $run $([ -f $run/checkpoint.pt ] && echo --resume) \
    --steps "${STEPS:-3000}" --minutes 10000 --lr-schedule cosine --spp 1 2 4 8 --max-sequences 19 \
    --test data/curves-test --val-every 500 --threads 1 --seed 0 --quiet
  mkdir -p /tmp/cheap-wskpn
  mcdenoise export $run --out /tmp/cheap-wskpn/cos-${1#wskpn-3-aa-}.onnx
}
for s in "$@"; do one "$s" > /tmp/cheap-wskpn-cos-$s.log 2>&1 & done
wait
