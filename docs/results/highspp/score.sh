#!/usr/bin/env bash
# Scores the high-spp runs of train.sh (issue 15) as a user would see them, beside the shipped models
# and Open Image Denoise, all through the runtime API:
#   - curves-test stills at 1, 2, 4, 8 spp (the first frame of each of its 4 sequences);
#   - the hand-made held-out scenes (never trained on) at 1 and 4 spp, through docs/results/long/eval.sh,
#     and at 8 spp, the spp these models are for, with every shipped model beside them.
# Usage: bash docs/results/highspp/score.sh [RUN...]   (default: docs/results/highspp/{wskpn-mr,nbg-7l-3g})
#   SETS="long-slow ...": only those held-out sets (default: every one rendered under data/)
# Writes <run>/stills-curves-test-<spp>spp.json, docs/results/long/<set>/<run name>-<spp>spp.json,
# docs/results/highspp/<set>-8spp.json and baseline/; python docs/results/highspp/table.py makes table.md.
set -euo pipefail
cd "$(dirname "$0")/../../.."
out=docs/results/highspp
runs=("$@"); [ ${#runs[@]} -gt 0 ] || runs=("$out/wskpn-mr" "$out/nbg-7l-3g")
onnx=()
for r in "${runs[@]}"; do
  f="/tmp/$(basename "$r").onnx"
  mcdenoise export "$r" --out "$f"
  onnx+=("$f")
  for spp in 1 2 4 8; do
    # stills newer than the run's checkpoint are kept (a fresh machine need not render curves-test again)
    [ ! -f "$r/stills-curves-test-${spp}spp.json" ] || [ "$r/checkpoint.pt" -nt "$r/stills-curves-test-${spp}spp.json" ] || continue
    mcdenoise evaluate "$f" --no-oidn --data data/curves-test --spp $spp --stills --threads "$(nproc)" \
      --json "$r/stills-curves-test-${spp}spp.json"
  done
done
# The shipped models' stills the scale baseline lacks (wskpn-6, wskpn-3 and Open Image Denoise are in
# docs/results/scale/baseline).
mkdir -p "$out/baseline"
for spp in 1 2 4 8; do
  [ -f "$out/baseline/stills-curves-test-${spp}spp.json" ] || mcdenoise evaluate models/nbg-2l-3g.onnx models/wskpn-6e.onnx \
    --no-oidn --data data/curves-test --spp $spp --stills --threads "$(nproc)" --json "$out/baseline/stills-curves-test-${spp}spp.json"
done
sets=()
for set in ${SETS:-heldout-room_window heldout-lamp_occluder long-slow long-medium long-fast}; do
  [ -f "data/$set/manifest.json" ] && sets+=("$set")
done
[ ${#sets[@]} -gt 0 ] || { echo "score.sh: no held-out set rendered (docs/render-queue.sh)" >&2; exit 0; }
RUNS="${runs[*]}" BASELINE=0 bash docs/results/long/eval.sh "${sets[@]}"
# At 8 spp every shipped model (but the runs' own shipped copies, whose names the runs' files share)
shipped=()
for m in models/*.onnx; do
  case " ${runs[*]##*/} " in *" $(basename "$m" .onnx) "*) ;; *) shipped+=("$m") ;; esac
done
for set in "${sets[@]}"; do
  mcdenoise evaluate oidn-fast svgf "${shipped[@]}" "${onnx[@]}" \
    --data "data/$set" --spp 8 --warmup 8 --threads "$(nproc)" --json "$out/$set-8spp.json"
done
