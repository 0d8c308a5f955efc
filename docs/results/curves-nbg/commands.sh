#!/usr/bin/env bash
# Issue 15 item 2, its NBG spec: learning curves of nbg-2l-3g-aa (the NBG file shipped trained) from
# scratch, on a 2-vCPU CPU, one thread per process: test PSNR (curves-test) against training
# examples seen, for three nested training-set sizes and two GuideNet widths. Re-running resumes
# every run folder below (raise --steps to extend the curves).
# Data: data/nbg-train (48 procedural scenes x 8 frames, 128x128, 8 stored spp, seed 12; 38
# training sequences after the seed-hash validation split) and data/curves-test (4 held-out scenes,
# seed 11): the render commands are in docs/results/nbg-retrain/train.sh and docs/results/curves/commands.sh.
# Flags as the WSKPN curves (docs/results/curves): spp drawn from 1, 2, 4, 8 per item; the spec's
# own batch (8), crop (64) and 2-frame windows (8-frame windows would cost 4x the steps' time).
set -e
cd "$(dirname "$0")/../../.."
run() { mcdenoise curves nbg-2l-3g-aa --data data/nbg-train --test data/curves-test --out docs/results/curves-nbg \
  --sequences 9 19 38 --steps "${STEPS:-2000}" --eval-every 500 --spp 1 2 4 8 --threads 1 --vary width "$@"; }
# one process per width (two cores), then both, which only writes the chart and the table
run 8 > /tmp/curves-nbg-8.log 2>&1 &
run 16 > /tmp/curves-nbg-16.log 2>&1 &
wait
run 8 16
