#!/usr/bin/env bash
# The learning curves' data (commands.sh), rendered only where missing: what the A/B scripts of
# later sittings (anf-demod, albedo-history) train and validate on. About 12 minutes for
# curves-train with --workers 2 on a 2-core VM, 8 for curves-test on one worker.
#   data/curves-train  24 procedural scenes x 8 frames, 128x128, 8 stored spp, 256-spp references, half enclosed rooms
#   data/curves-test   4 held-out scenes (another seed), 512-spp references
set -euo pipefail
cd "$(dirname "$0")/../../.."
[ -f data/curves-test/manifest.json ] || mcdenoise render --out data/curves-test --scenes 4 --frames 8 --spp 8 \
  --ref-spp 512 --size 128x128 --seed 11 --enclosed 0.5 < /dev/null
[ -f data/curves-train/manifest.json ] || mcdenoise render --out data/curves-train --scenes 24 --frames 8 --spp 8 \
  --ref-spp 256 --size 128x128 --seed 10 --enclosed 0.5 --workers 2 < /dev/null
