#!/usr/bin/env bash
# Issue 17 item 4: NBG's splat without a scatter. Times the graphs of nbg-2l-1g and nbg-2l-3g
# (untrained: the splat has no weights, the time does not depend on them) in onnxruntime and
# torch eager, at the commit before the change (8f17409, ScatterElements with reduction add)
# and at the current tree (block MatMuls), one after the other on the same machine.
# Writes docs/results/nbg-splat/{before,after}-<threads>t.txt.
set -e
cd "$(dirname "$0")/../../.."
out=docs/results/nbg-splat
old=$(mktemp -d)/before
git worktree add -f -q "$old" 8f17409
# the checkout's folders under the package name, ahead of the editable install's finder
for d in runtime training export models models_spec samples; do ln -s ../$d "$old/mcdenoise/$d"; done
for t in 1 2; do
  (cd "$old" && python -m mcdenoise.export.timing --what models --specs nbg-2l-1g nbg-2l-3g \
     --sizes 256x256 1280x720 --threads $t --repeats 5) 2>/dev/null | tee "$out/before-${t}t.txt"
  python -m mcdenoise.export.timing --what models --specs nbg-2l-1g nbg-2l-3g \
     --sizes 256x256 1280x720 --threads $t --repeats 5 2>/dev/null | tee "$out/after-${t}t.txt"
done
git worktree remove --force "$old"
