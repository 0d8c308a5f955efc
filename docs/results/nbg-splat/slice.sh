#!/usr/bin/env bash
# Issue 17 item 4's bar, nbg-2l-3g no slower in onnxruntime than in torch eager at 720p (the bench
# of 2026-12-05 had it 6% slower: 930 against 878 ms, the slice 370 against 107). The slice now
# divides each grid row once by its weight sum (no mask, cast and concatenation over the grid) and
# accumulates the 8 corners channels first. Times the graphs of both models (untrained; the
# slice's cost does not depend on the weights) in onnxruntime and torch eager at the commit before
# (06cff45) and at the current tree, one after the other, 2 threads.
# Writes docs/results/nbg-splat/slice-{before,after}-2t.txt.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/nbg-splat
old=$(mktemp -d)/before
git worktree add -f -q "$old" 06cff45
trap 'git worktree remove --force "$old"' EXIT
timing() { python -m mcdenoise.export.timing --what models --specs nbg-2l-1g nbg-2l-3g --sizes 256x256 1280x720 \
  --threads 2 --repeats 7 2>/dev/null; }
# the checkout's folders under the package name, ahead of the editable install's finder
for d in runtime training export models models_spec samples; do ln -s ../$d "$old/mcdenoise/$d"; done
(cd "$old" && timing) | tee "$out/slice-before-2t.txt"
timing | tee "$out/slice-after-2t.txt"
