#!/usr/bin/env bash
# The GPU check of issue 17, one command on a lent GPU machine, from the repository root there:
#   run: bash docs/results/device/gpu_check.sh      (carry: .gpu)
# Before: put the wheels the machine lacks into .gpu/wheels on this side (it has no network):
#   pip download --no-deps -d .gpu/wheels onnxruntime-gpu OpenEXR pyoidn
# (onnxruntime-gpu is large; the lean carry limit is 64 MiB, so check the size first).
# Writes to $OUT: bench (mcdenoise bench --device cuda) and driver.txt (whole frames through
# the driver at 1280x720: numpy prelude with the state on the host, the prelude graphs with the
# state on the host, and the default on a device, the prelude graphs with the state kept on the
# device with IO binding; each row's graph time beside its whole frame).
# MODELS="models/wskpn-3.onnx models/wskpn-6e-aa.onnx" limits both to those files (default: every
# shipped model, 14 since 2026-12-06; anf-s and ndle-s are the slow ones when device time is short).
set -euo pipefail
site="$PWD/.gpu/site"
mkdir -p "$site" "$OUT"
python -m pip install -q --no-index --no-deps --target "$site" .gpu/wheels/*.whl
# The package without building it: its namespace as links to the checkout's folders.
mkdir -p "$site/mcdenoise"
cp mcdenoise/__init__.py "$site/mcdenoise/"
for d in runtime training export; do ln -sfn "$PWD/$d" "$site/mcdenoise/$d"; done
export PYTHONPATH="$site"
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > "$OUT/gpu.txt" || true
read -r -a models <<< "${MODELS-}"
python -m mcdenoise.runtime.cli bench ${models[@]+"${models[@]}"} --device cuda --no-quality --frames 20 --warmup 5 --out "$OUT/bench" \
  > "$OUT/bench.log" 2>&1 || echo "bench failed (see bench.log)"
MODELS="${MODELS-}" python - > "$OUT/driver.txt" 2>&1 <<'PY'
import os
import statistics
from mcdenoise.runtime.denoiser import Denoiser
from mcdenoise.runtime.frames import Frame
from mcdenoise.training.harness import synthetic_frame
from mcdenoise.training.methods import shipped_models
for path in os.environ.get("MODELS", "").split() or shipped_models():
    for prelude, bound in (("numpy", False), ("graph", False), ("graph", True)):
        den = Denoiser.load(path, providers=["CUDAExecutionProvider", "CPUExecutionProvider"], prelude=prelude,
                            io_binding=bound, log=lambda m: None)
        for t in range(25):
            den(Frame(**synthetic_frame(1280, 720, t)))
        rows = den.timings[5:]
        med = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
        print(path, prelude, "io_binding" if bound else "host state", den.session.get_providers()[0],
              {k: round(v, 2) for k, v in med.items()})
PY
cat "$OUT/driver.txt"
