#!/usr/bin/env bash
# Issue 15 item 2: the first learning curves, on a 2-vCPU CPU (one thread per process).
# Everything here is re-creatable: the data by the two render commands (about 15 s a frame
# here), the runs by the curves command, which resumes every run folder below (raise --steps
# to extend the curves; the run folders are committed so a next sitting continues exactly).
set -e
cd "$(dirname "$0")/../../.."
# 24 procedural scenes x 8 frames, 128x128, 8 stored spp, 256-spp references, half enclosed rooms
mcdenoise render --out data/curves-train --scenes 24 --frames 8 --spp 8 --ref-spp 256 --size 128x128 --seed 10 --enclosed 0.5
# held-out test scenes (another seed), 512-spp references
mcdenoise render --out data/curves-test --scenes 4 --frames 8 --spp 8 --ref-spp 512 --size 128x128 --seed 11 --enclosed 0.5
# wskpn-6 at two widths on nested 4 / 9 / 19 training sequences (of the 24: the seed-hash split holds 5 out):
# first 1000 steps (scored every 200), then resumed to 3000 (scored every 500), one process per
# width (WIDTHS='[8]' or '[16]'; the same --out), and last with both widths, which only writes the chart.
mcdenoise curves wskpn-6 --data data/curves-train --test data/curves-test --out docs/results/curves \
  --sequences 4 9 19 --vary widths '[8]' '[16]' --steps 1000 --eval-every 200 --spp 1 2 4 8 --threads 1
mcdenoise curves wskpn-6 --data data/curves-train --test data/curves-test --out docs/results/curves \
  --sequences 4 9 19 --vary widths ${WIDTHS:-'[8]' '[16]'} --steps 3000 --eval-every 500 --spp 1 2 4 8 --threads 1
