# Sourced by train.sh, eval.sh and arms.sh (from the repository root).
# zero_shot SPEC: prints the path of SPEC's zero-shot file (the base model's shipped weights under the
# -aa spec: what every run here starts from), made in /tmp/nbg-retrain if missing. models/nbg-2l-3g-aa.onnx
# itself ships retrained since 2026-12-07, so it is no longer the start.
zero_shot() {
  local f=/tmp/nbg-retrain/$1-zero.onnx
  mkdir -p /tmp/nbg-retrain
  [ -f "$f" ] || mcdenoise export "models/${1%-aa}.onnx" --protocol-from "models_spec/$1.toml" --out "$f" >&2
  echo "$f"
}

# score FILE... on one set the way this folder's tables read it:
# score SET PREFIX FILE...: sequences through the driver with history at 1, 4 and 8 spp (after WARMUP
# warm-up frames, default 8) and stills (first frames, no history) at 1, 2, 4 and 8 spp, into
# docs/results/nbg-retrain/SET/PREFIX<spp>spp.json and PREFIXstills-<spp>spp.json.
score() {
  local set=$1 pre=$2 spp dir=docs/results/nbg-retrain/$1
  shift 2
  mkdir -p "$dir"
  for spp in 1 4 8; do
    mcdenoise evaluate "$@" --no-oidn --data "data/$set" --spp $spp --warmup "${WARMUP:-8}" \
      --threads "$(nproc)" --json "$dir/$pre${spp}spp.json"
  done
  for spp in 1 2 4 8; do
    mcdenoise evaluate "$@" --no-oidn --data "data/$set" --spp $spp --stills \
      --threads "$(nproc)" --json "$dir/${pre}stills-${spp}spp.json"
  done
}
